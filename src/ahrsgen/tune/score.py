"""One log scored with one set of values (runs in the fleet's workers)."""
from __future__ import annotations

import math

from ahrsgen.tune.cases import load_case
from ahrsgen.tune.space import set_text

METRICS = {"total": "total_rms", "inclination": "inclination_rms", "heading": "heading_rms"}
PENALTY_DEG = 180.0          # a log whose run failed scores as a diverged estimate


def evaluate(task: dict) -> dict:
    """One log scored with one set of values: {'label', 'score'} or {'label', 'error'}."""
    from ahrsgen.bench import Estimator, score
    case = task["case"]
    try:
        log = load_case(case)
        # runtime engine: the real-valued parameters are set in C per run on one build
        # (built once per worker and structural combination); baked: one build per trial
        rt = {k: v for k, v in task["values"].items() if k in task["runtime"]}
        folded = {k: v for k, v in task["values"].items() if k not in rt}
        est = Estimator(task["filter"], "filter", task["heading"], filter=task["filter"],
                        sets=list(task["sets"]) + [set_text(k, v) for k, v in folded.items()],
                        config=task["config"], runtime=rt)
        q, heading, _ = est.run(log)
        return {"label": case.label, "score": score(q, log, heading)}
    except Exception as e:         # a value that breaks a run scores as divergence, and says why
        return {"label": case.label, "error": f"{type(e).__name__}: {e}"}


def case_error(result: dict, metric: str) -> float:
    if "error" in result:
        return PENALTY_DEG
    v = result["score"][METRICS[metric]]
    return float(v) if math.isfinite(v) else PENALTY_DEG
