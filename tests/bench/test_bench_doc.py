"""docs/bench.md's results are one `ahrsgen bench` run's: its JSON is committed
(docs/data/bench.json) and the doc's marked block must be exactly that JSON's bench.md, as
`ahrsgen.bench.report.markdown` writes it (`python -m studies.bench_doc` writes both). The run
itself is not repeated here (278 s); this checks that no figure of the doc is other than the
run's, and that each table holds what the JSON holds, read back cell by cell."""
from __future__ import annotations

import json
import re
import sys

from docs_tables import ROOT, numbers, table

sys.path.insert(0, str(ROOT))
from studies import bench_doc        # noqa: E402

DOC = ROOT / "docs" / "bench.md"
REP = json.loads(bench_doc.DATA.read_text())


def _block(name: str) -> list[str]:
    text = DOC.read_text()
    m = re.search(rf"<!-- bench_doc.py: {name} -->\n(.*?)<!-- end bench_doc.py -->", text, re.S)
    assert m, name
    return m.group(1).rstrip("\n").splitlines()


def test_the_results_block_is_the_committed_runs_bench_md():
    assert _block("results") == bench_doc.results_lines(REP)
    assert _block("run") == bench_doc.header_lines(REP)
    assert REP["command"].startswith("ahrsgen bench") and not REP["quick"] and not REP["run_errors"]


def test_the_tables_hold_the_json_figures():
    """Independent of the markdown writer: the tables read back from the doc against the JSON."""
    checked = 0
    for scen, ests in REP["scenarios"].items():
        for row in table("docs/bench.md", f"#### {scen} ("):
            m = ests[row["estimator"]]
            for col, key in (("total RMS", "total_rms"), ("heading RMS", "heading_rms"), ("roll RMS", "roll_rms")):
                mean, sd = row[col].split(" ± ")
                assert float(mean) == round(m[key]["mean"], 2) and float(sd) == round(m[key]["sd"], 2), (scen, row)
                checked += 1
    for row in table("docs/bench.md", "### BROAD (BROAD's method"):
        m = REP["broad"]["mean"][row["estimator"]]
        assert float(row["total RMSE"]) == round(m["total_rms"]["mean"], 2), row
        checked += 1
    for row in table("docs/bench.md", "### Cost per step"):
        c = REP["cost"][row["filter"]]
        assert numbers(row["state bytes"]) == [str(c["state_bytes"])] and float(row["ns/step"]) == round(c["ns_per_step"])
        checked += 1
    assert checked > 300
