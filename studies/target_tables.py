"""Writes the footprint tables of docs/target.md and README.md from one `ahrsgen target` run.

    PYTHONPATH=src .venv/bin/python -m ahrsgen target all --peers --json build/target/target.json
    PYTHONPATH=src .venv/bin/python -m studies.target_tables build/target/target.json

Each table stands between a line `<!-- target_tables.py: NAME -->` and a line
`<!-- end target_tables.py -->` (studies/doc_blocks.py). tests/target/test_target.py re-measures every
figure of these tables (tests/docs_tables.py reads them back).
"""
from __future__ import annotations

import json
import sys
from pathlib import Path

from studies.doc_blocks import ROOT, replace_block

WRITER = "target_tables.py"

# docs/target.md's columns; the checker in tests/target/test_target.py names the same headers
FULL_HEADER = ("| filter | build | scenario (steps) | flash B | state B | stack B static / measured / -O0 "
               "| instructions/step | est. cycles/step | vdiv+vsqrt/step |")


def n(x: float) -> str:
    """A whole number with a space between thousands: 18356 -> "18 356"."""
    return f"{round(x):,}".replace(",", " ")


def full_table(results: list[dict]) -> list[str]:
    """One row a build: every figure of the footprint the docs state."""
    lines = [FULL_HEADER, "|" + "---|" * 9]
    for r in results:
        fp = r["footprint"]
        lines.append(f"| {fp['filter'].removeprefix('peer:')} | {fp['opt']} | {r['scenario']} ({n(r['steps'])}) "
                     f"| {n(fp['flash_bytes'])} | {n(fp['state_bytes'])} "
                     f"| {n(fp['stack_bytes'])} / {n(fp['stack_measured_bytes'])} / {n(fp['stack_o0_bytes'])} "
                     f"| {n(fp['instructions_mean'])} | {n(fp['cycles_est_mean'])} "
                     f"| {fp['vdiv_vsqrt_per_step']:.1f} |")
    return lines


def readme_table(results: list[dict]) -> list[str]:
    """The README's short table: -O2 and -Os side by side, one row a filter."""
    by = {(r["filter"], r["opt"]): r["footprint"] for r in results}
    lines = ["| filter | flash B (-O2 / -Os) | state B | stack B (worst / measured) "
             "| instructions per step (-O2 / -Os) | est. cycles per step (-O2 / -Os) |",
             "|---|---|---|---|---|---|"]
    for name in dict.fromkeys(r["filter"] for r in results):
        o2, os_ = by[(name, "-O2")], by[(name, "-Os")]
        label = name
        params = json.loads((ROOT / "generated" / name / "manifest.json").read_text())["params"]
        if "n_particles" in params:
            label += f" (N = {params['n_particles']})"
        lines.append(f"| {label} | {n(o2['flash_bytes'])} / {n(os_['flash_bytes'])} | {n(o2['state_bytes'])} "
                     f"| {n(o2['stack_bytes'])} / {n(o2['stack_measured_bytes'])} "
                     f"| {n(o2['instructions_mean'])} / {n(os_['instructions_mean'])} "
                     f"| {n(o2['cycles_est_mean'])} / {n(os_['cycles_est_mean'])} |")
    return lines


def main(argv: list[str]) -> int:
    if len(argv) != 1:
        sys.exit(__doc__)
    report = json.loads(Path(argv[0]).read_text())
    results = [r for r in report["results"] if r["precision"] == "float" and not r["footprint"]["variant"]]
    order = {"qcf": 0, "mekf": 1, "adukf": 2, "cpf": 3}
    results.sort(key=lambda r: (order.get(r["filter"], 9), r["filter"], r["opt"] != "-O2"))
    if not report["peers"]:
        sys.exit("the report has no peers: run `ahrsgen target all --peers --json FILE`")
    # the peers run on fixedwing_gps (`ahrsgen target --peers`), every step counted by QEMU
    peers = [{"scenario": "fixedwing_gps", "steps": fp["instructions_steps"], "footprint": fp}
             for fp in report["peers"]]
    replace_block(ROOT / "docs" / "target.md", WRITER, "filters", full_table(results))
    replace_block(ROOT / "docs" / "target.md", WRITER, "peers", full_table(peers))
    replace_block(ROOT / "README.md", WRITER, "filters", readme_table(results))
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
