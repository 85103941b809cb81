"""Writes docs/bench.md's results from one `ahrsgen bench` run, and keeps that run's JSON.

    PYTHONPATH=src .venv/bin/python -m ahrsgen bench -o /tmp/bench
    PYTHONPATH=src .venv/bin/python -m studies.bench_doc /tmp/bench/bench.json <commit>

The run's bench.json is copied to docs/data/bench.json (only what the tables need) and the
block `<!-- bench_doc.py: results -->` of docs/bench.md becomes that JSON's bench.md
(`ahrsgen.bench.report.markdown`) with its headings one level down and the plots named by
path. tests/bench/test_bench_doc.py checks that the block equals what docs/data/bench.json says.
"""
from __future__ import annotations

import json
import re
import sys
from pathlib import Path

from studies.doc_blocks import ROOT, replace_block

WRITER = "bench_doc.py"
DATA = ROOT / "docs" / "data" / "bench.json"
KEYS = ("written_by", "command", "quick", "seeds", "date_utc", "host", "build_errors", "notes",
        "scenarios", "scenario_options", "broad", "px4", "run_errors", "cost", "cost_log",
        "seconds", "task_cpu_seconds", "plots", "commit")


def results_lines(rep: dict) -> list[str]:
    """The run's bench.md as docs/bench.md holds it: the title left out, headings one level
    down, each plot named by its path in the bench's output folder."""
    from ahrsgen.bench.report import markdown
    text = markdown(rep)
    text = re.sub(r"\nError over time \(seed 0\): !\[[^\]]*\]\(([^)]*)\)",
                  r"\nError over time (seed 0): `\1` in the bench's output folder.", text)
    lines = text.rstrip("\n").splitlines()
    assert lines[0].startswith("# ahrsgen bench results")
    return [("#" + ln if ln.startswith("#") else ln) for ln in lines[1:]]


def header_lines(rep: dict) -> list[str]:
    return [f"Written by `python -m studies.bench_doc` from the run `{rep['command']}` on commit "
            f"{rep['commit']} ({rep['date_utc']}); its JSON is docs/data/bench.json."]


def main(argv: list[str]) -> int:
    if len(argv) != 2:
        sys.exit(__doc__)
    rep = json.loads(Path(argv[0]).read_text())
    rep = {k: rep[k] for k in KEYS if k in rep} | {"commit": argv[1]}
    DATA.write_text(json.dumps(rep, indent=1, ensure_ascii=False) + "\n")
    doc = ROOT / "docs" / "bench.md"
    replace_block(doc, WRITER, "run", header_lines(rep))
    replace_block(doc, WRITER, "results", results_lines(rep))
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
