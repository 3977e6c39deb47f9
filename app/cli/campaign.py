"""``aar-dock campaign``: Monte-Carlo docking runs on Dask → CSV, summary JSON, histogram."""

from __future__ import annotations

import argparse
import json
import sys

from app.cli.simulate import add_docking_options, rounded


def register(subparsers: argparse._SubParsersAction) -> None:  # type: ignore[type-arg]
    p = subparsers.add_parser("campaign", help="Monte-Carlo docking campaign on Dask")
    p.add_argument("--runs", type=int, required=True, help="number of runs (seeds first-seed..)")
    add_docking_options(p)
    p.add_argument(
        "--scheduler", default=None, help="Dask scheduler address (default: LocalCluster)"
    )
    p.add_argument("--workers", type=int, default=2, help="LocalCluster worker processes")
    p.add_argument(
        "--station-keep", type=float, default=1.0, help="seconds after contact (default 1)"
    )
    p.add_argument("--first-seed", type=int, default=0)
    p.add_argument("--out", default="campaign_out", help="output directory")
    p.add_argument("--no-progress", action="store_true")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    if args.runs < 1:
        print("error: --runs must be >= 1", file=sys.stderr)
        return 2
    if args.workers < 1:
        print("error: --workers must be >= 1", file=sys.stderr)
        return 2
    from app.sim.campaign import run_campaign, summarise, write_outputs
    from app.sim.docking import DockingConfig

    try:
        cfg = DockingConfig(
            plant=args.plant,
            turbulence=args.turbulence,
            vision=not args.truth_measurements,
            camera_hz=args.camera_hz,
            matcher=args.matcher,
            render_mode="windows" if args.roi else args.render,
            imperfections=args.imperfections,
            station_keep_s=args.station_keep,
            hold_gap_on_lost_lock=not args.backoff_on_lost_lock,
            hose_model=args.hose,
        )
        cfg.validate()
    except ValueError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    client = None
    if args.scheduler:
        from distributed import Client

        try:
            client = Client(args.scheduler, timeout="10s")
        except OSError as exc:
            print(f"error: cannot reach Dask scheduler {args.scheduler}: {exc}", file=sys.stderr)
            return 2
    if cfg.vision and client is None:
        # compile the navigation loops once here (cached on disk) rather than in every worker
        from app.sim.warmup import compile_kernels

        compile_kernels()
    bar = None
    if not args.no_progress:
        from tqdm import tqdm

        bar = tqdm(total=args.runs, desc=f"campaign {args.turbulence}", file=sys.stderr)

    def tick(row: dict) -> None:  # type: ignore[type-arg]
        if bar is not None:
            bar.update(1)
            bar.set_postfix(outcome=row["outcome"])

    try:
        rows = run_campaign(
            cfg,
            args.runs,
            first_seed=args.first_seed,
            client=client,
            workers=args.workers,
            on_result=tick,
        )
    finally:
        if bar is not None:
            bar.close()
        if client is not None:
            client.close()
    summary = summarise(rows, cfg)
    paths = write_outputs(args.out, rows, summary)
    print(json.dumps(rounded({k: v for k, v in summary.items() if k != "config"})))
    print(f"wrote {paths['csv']}, {paths['json']}, {paths['png']}", file=sys.stderr)
    return 0
