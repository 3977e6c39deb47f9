"""Merge campaign folders (``aar-dock campaign --out DIR``, each with ``runs.csv``) into one
table of outcomes with Wilson 95 % intervals, per condition — for campaigns run in chunks of
seeds so that a cut-off loses at most one chunk.

    python benchmarks/merge_campaigns.py runs/std_mod_* runs/harsh_light_* runs/harsh_mod_*

A folder's condition is its name up to the last ``_`` (``std_mod_100000`` → ``std_mod``).
Prints a Markdown table: runs, seeds, each outcome's count, capture and departure rates
with their intervals, the envelope's extremes over all runs (α, load factor, bank, height
lost, KCAS), closure and lateral speed at contact, and the summed wall time.
"""

from __future__ import annotations

import csv
import math
import re
import sys
from collections import defaultdict
from pathlib import Path

from app.sim.campaign import summarise
from app.sim.docking.outcomes import OUTCOMES

NUMERIC = {"seed", "aborts", "frames_dropped", "frames_duplicated", "recoveries"}


def _value(key: str, text: str) -> object:
    if text in ("", "None"):
        return None if key != "traceback" else None
    if key in ("captured", "hose_whip_risk"):
        return text == "True"
    if key in NUMERIC:
        return int(float(text))
    try:
        return float(text)
    except ValueError:
        return text


def read_rows(folder: Path) -> list[dict[str, object]]:
    with (folder / "runs.csv").open() as fh:
        return [{k: _value(k, v) for k, v in row.items()} for row in csv.DictReader(fh)]


def _log_wall_s(log: Path) -> float:
    """The campaign's wall time from its progress bar's last ``[MM:SS<`` (0 without a log)."""
    if not log.exists():
        return 0.0
    found = re.findall(r"\[(?:(\d+):)?(\d+):(\d+)<", log.read_text(errors="replace"))
    if not found:
        return 0.0
    h, m, sec = found[-1]
    return 3600.0 * int(h or 0) + 60.0 * int(m) + int(sec)


def main(folders: list[str]) -> int:
    groups: dict[str, list[dict[str, object]]] = defaultdict(list)
    wall: dict[str, float] = defaultdict(float)
    for name in folders:
        folder = Path(name)
        if not (folder / "runs.csv").exists():
            print(f"skip {folder} (no runs.csv: unfinished)", file=sys.stderr)
            continue
        cond = folder.name.rsplit("_", 1)[0]
        groups[cond].extend(read_rows(folder))
        wall[cond] += _log_wall_s(folder.with_suffix(".log"))
    print(
        "| condition | runs | seeds | "
        + " | ".join(OUTCOMES)
        + " | capture (95 % CI) | departure (95 % CI) | α min…max (°) | load factor (g) | bank max (°) | height lost max (m) | KCAS | closure at contact (m/s) | lateral at contact p50 / p95 (m/s) |"
    )
    print("|" + "---|" * (17))
    for cond, rows in groups.items():
        s = summarise(rows)  # type: ignore[arg-type]
        env = {
            k: [
                float(r[k])
                for r in rows
                if isinstance(r.get(k), float) and math.isfinite(float(r[k]))
            ]
            for k in (
                "alpha_min_deg",
                "alpha_max_deg",
                "load_factor_min_g",
                "load_factor_max_g",
                "bank_max_deg",
                "height_lost_m",
                "kcas_min",
                "kcas_max",
            )
        }  # type: ignore[arg-type]
        lo, hi = s["capture_rate_ci95"]
        dlo, dhi = s["departure_rate_ci95"]
        seeds = s["seeds"]
        counts = " | ".join(str(s["outcomes"][k]) for k in OUTCOMES)

        def f(v: object, d: int = 2) -> str:
            return "–" if v is None else f"{float(v):.{d}f}"  # type: ignore[arg-type]

        print(
            f"| {cond} | {s['runs']} | {seeds[0]}–{seeds[1]} | {counts} | "
            f"{100 * s['capture_rate']:.1f} % ({100 * lo:.1f}–{100 * hi:.1f}) | "
            f"{100 * s['departure_rate']:.1f} % ({100 * dlo:.1f}–{100 * dhi:.1f}) | "
            f"{min(env['alpha_min_deg']):.1f}…{max(env['alpha_max_deg']):.1f} | "
            f"{min(env['load_factor_min_g']):.2f}…{max(env['load_factor_max_g']):.2f} | "
            f"{max(env['bank_max_deg']):.1f} | {max(env['height_lost_m']):.1f} | "
            f"{min(env['kcas_min']):.0f}…{max(env['kcas_max']):.0f} | "
            f"{f(s['closure_at_contact_min_mps'])}…{f(s['closure_at_contact_max_mps'])} | "
            f"{f(s['lateral_speed_at_contact_p50_mps'])} / {f(s['lateral_speed_at_contact_p95_mps'])} |"
        )
    for cond, w in wall.items():
        print(f"\n{cond}: campaign wall time {w / 60:.1f} min (sum of its chunks)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
