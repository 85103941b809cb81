"""A generated build's manifest -> the layout header the C harnesses read (which state fields
are quaternions, a covariance, weights; the status bits), and where builds are found or made."""
from __future__ import annotations

import json
import math
from pathlib import Path

from ahrsgen import paths

FUZZ_DIR = paths.harness_dir("fuzz")
C_DIR = paths.harness_dir("c")
GENERATED = paths.CHECKOUT / "generated" if paths.CHECKOUT else None   # committed builds (checkout only)
BUILD = paths.build_dir("harden", "AHRSGEN_BUILD_HARDEN")


class HardenError(RuntimeError):
    pass


def load_manifest(gen_dir: Path) -> dict:
    return json.loads((Path(gen_dir) / "manifest.json").read_text())


def _is_quat(f: dict) -> bool:
    if f["type"] != "real" or f["count"] % 4:
        return False
    doc = f.get("doc", "").lower()
    return f["name"] == "q" or (f["name"].startswith("q_") and f["count"] == 4) or "quaternion" in doc


def _cov_dim(f: dict) -> int | None:
    if f["type"] != "real":
        return None
    n = math.isqrt(f["count"])
    if n < 2 or n * n != f["count"]:
        return None
    doc = f.get("doc", "").lower()
    if f["name"] == "P" or "covariance" in doc:
        return n
    return None


def invariant_plan(man: dict) -> dict:
    """Which state fields get which check (read from the manifest; reported with the results)."""
    fields = man["structs"]["state"]["fields"]
    names = {f["name"] for f in fields}
    return {
        "finite": [f["name"] for f in fields if f["type"] == "real"],
        "quaternions": [(f["name"], f["count"] // 4) for f in fields if _is_quat(f)],
        "covariances": [(f["name"], _cov_dim(f)) for f in fields if _cov_dim(f)],
        "weights": next((f["name"] for f in fields if f["name"] == "weights" and f["type"] == "real"), None),
        "initialised": "initialised" if "initialised" in names else None,
    }


def layout_header(man: dict) -> str:
    fields = man["structs"]["state"]["fields"]
    plan = invariant_plan(man)
    by = {f["name"]: f for f in fields}

    def ptr(name):
        return f"&(s)->{name}" if by[name]["count"] == 1 else f"(s)->{name}"

    status_all = 0
    for v in man["status"].values():
        status_all |= int(v)
    lines = [
        f"/* ahrs_layout.h for {man['filter']} ({man['precision']}): written by src/ahrsgen/check/layout.py from",
        " * manifest.json - do not edit. See src/ahrsgen/sim/fuzz/ahrs_invariants.h. */",
        "#ifndef AHRS_LAYOUT_H", "#define AHRS_LAYOUT_H",
        f"#define AHRS_PREFIX {man['prefix']}",
        f"#define AHRS_HEADER \"{man['files']['header']}\"",
        f"#define AHRS_REAL {man['precision']}",
        f"#define AHRS_REFUSED_MASK {int(man['refused_mask'])}u",
        f"#define AHRS_STATUS_ALL {status_all}u",
        "#define AHRS_FOR_EACH_REAL(X, s) " + " ".join(
            f'X("{n}", {ptr(n)}, {by[n]["count"]})' for n in plan["finite"]),
        "#define AHRS_FOR_EACH_QUAT(X, s) " + " ".join(
            f'X("{n}", {ptr(n)}, {nq}, {1 if nq > 1 else 0})' for n, nq in plan["quaternions"]),
    ]
    if plan["covariances"]:
        lines.append("#define AHRS_FOR_EACH_COV(X, s) " + " ".join(
            f'X("{n}", (s)->{n}, {d})' for n, d in plan["covariances"]))
    if plan["weights"]:
        lines += [f"#define AHRS_WEIGHTS_FIELD {plan['weights']}",
                  f"#define AHRS_WEIGHTS_COUNT {by[plan['weights']]['count']}"]
        if "weight_sum" in by and by["weight_sum"]["type"] == "real" and by["weight_sum"]["count"] == 1:
            lines.append("#define AHRS_WEIGHT_SUM_FIELD weight_sum")
    if plan["initialised"]:
        lines.append("#define AHRS_INIT_FIELD initialised")
    lines += ["#endif", ""]
    return "\n".join(lines)


def resolve_dir(filter_or_dir: str | Path) -> Path:
    """A directory with manifest.json, the committed generated/NAME of a checkout, or else any
    filter (name or filter folder, see ahrsgen.filters) generated with its defaults into the
    build directory."""
    p = Path(filter_or_dir)
    if (p / "manifest.json").exists():
        return p
    if GENERATED is not None and (GENERATED / str(filter_or_dir) / "manifest.json").exists():
        return GENERATED / str(filter_or_dir)
    from ahrsgen.generate import config, render
    cfg = config.resolve(str(filter_or_dir))       # unknown filter -> ConfigError naming it
    out = BUILD / "generated" / cfg.filter
    render.write(render.render(cfg), out)
    return out


def generated_dirs() -> list[Path]:
    """'all': the committed builds of a checkout, else every known filter's default build."""
    if GENERATED is not None and GENERATED.is_dir():
        return sorted(d for d in GENERATED.iterdir() if (d / "manifest.json").exists())
    from ahrsgen import filters
    return [resolve_dir(n) for n in filters.names()]
