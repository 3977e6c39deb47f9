"""Cost of the multi-body hose per simulated second at the docking tick (50 Hz), free trail with
a Dryden gust carried along the hose (the gusts drawn beforehand: the loop draws them anyway), and latched through a push-in; one core.

    .venv/bin/python benchmarks/bench_hose.py [--seconds 60] [--segments 20]

Prints the wall time per simulated second and per tick (after compilation), and the share of a
10 × real-time loop's budget (100 ms per simulated second) the hose takes. Asserts nothing.
"""

from __future__ import annotations

import os

for _v in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_v, "1")

import argparse  # noqa: E402
import time  # noqa: E402

import numpy as np  # noqa: E402

from app.sim.hose.atmosphere import flow_from_kcas  # noqa: E402
from app.sim.hose.contact import Coupling, push_in_path  # noqa: E402
from app.sim.hose.model import FrozenGust, MultibodyHose  # noqa: E402
from app.sim.hose.params import HoseParams  # noqa: E402
from app.sim.turbulence import DrydenTurbulence  # noqa: E402

DT = 0.02


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--seconds", type=float, default=60.0)
    ap.add_argument("--segments", type=int, default=20)
    args = ap.parse_args()
    flow = flow_from_kcas(15000, 230)
    hose = MultibodyHose(flow, HoseParams(segments=args.segments))
    turb = DrydenTurbulence("moderate", flow.airspeed_mps, DT, 15000 * 0.3048, seed=1)
    gust = FrozenGust(flow.airspeed_mps, DT)
    hose.step(DT, gust)  # compile / load the cache
    ticks = int(round(args.seconds / DT))
    gusts = [turb.step() for _ in range(2 * ticks)]  # the loop draws its gusts anyway
    t0 = time.perf_counter()
    for k in range(ticks):
        gust.push(gusts[k])
        hose.step(DT, gust)
    free = (time.perf_counter() - t0) / args.seconds
    hose.reset()
    c = Coupling(hose)
    start = hose.drogue_m
    c.contact(1.6, start)
    path = push_in_path(1.6, 3.0)
    axis = np.array([1.0, 0.0, 0.0])
    t0 = time.perf_counter()
    for k in range(1, ticks + 1):
        gust.push(gusts[ticks + k - 1])
        c.step(DT, start + path(k * DT) * axis, gust)
    latched = (time.perf_counter() - t0) / args.seconds
    print(f"segments {args.segments}, substeps per tick {hose.substeps(DT)}")
    for name, cost in (("free trail + gust", free), ("latched push-in + gust", latched)):
        print(
            f"{name:24s} {1e3 * cost:6.2f} ms per simulated s, {1e6 * cost * DT:6.1f} µs per tick, "
            f"{100 * cost / 0.1:5.1f} % of a 10× real-time budget"
        )


if __name__ == "__main__":
    main()
