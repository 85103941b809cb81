"""The C tools the checks run (clang with libFuzzer and the sanitizers, the host compiler) and
the cached build of a harness with one generated filter."""
from __future__ import annotations

import hashlib
import os
import shutil
import subprocess
from pathlib import Path

from ahrsgen.check.layout import BUILD, FUZZ_DIR, HardenError, layout_header, load_manifest

CLANG = os.environ.get("AHRSGEN_CLANG", "clang")

FUZZ_FLAGS = ["-std=c99", "-g", "-O1", "-fsanitize=fuzzer,address,undefined", "-fno-sanitize-recover=all",
              "-ffp-contract=off", "-fno-math-errno", "-Wall", "-Wextra"]


def have_tool(name: str) -> bool:
    return shutil.which(name) is not None


_FUZZER_OK: dict[str, bool] = {}


def clang_fuzzer_works() -> bool:
    """clang present and -fsanitize=fuzzer,address,undefined links."""
    if CLANG in _FUZZER_OK:
        return _FUZZER_OK[CLANG]
    ok = False
    if have_tool(CLANG):
        d = BUILD / "probe"
        d.mkdir(parents=True, exist_ok=True)
        src = d / "probe.c"
        src.write_text("#include <stdint.h>\n#include <stddef.h>\n"
                       "int LLVMFuzzerTestOneInput(const uint8_t *d, size_t n) { (void)d; (void)n; return 0; }\n")
        r = subprocess.run([CLANG, "-fsanitize=fuzzer,address,undefined", str(src), "-o", str(d / "probe")],
                           capture_output=True, text=True)
        ok = r.returncode == 0
    _FUZZER_OK[CLANG] = ok
    return ok


def _build(kind: str, gen_dir: Path, compiler: str, flags: list[str], harness: Path, tag: str = "") -> Path:
    man = load_manifest(gen_dir)
    layout = layout_header(man)
    src = gen_dir / man["files"]["source"]
    hdr = gen_dir / man["files"]["header"]
    h = hashlib.sha256()
    for p in (src, hdr, harness, FUZZ_DIR / "ahrs_invariants.h"):
        h.update(p.read_bytes())
    h.update(layout.encode())
    h.update(" ".join([compiler] + flags).encode())
    out = BUILD / f"{man['prefix']}-{kind}{tag}-{h.hexdigest()[:16]}"
    exe = out / f"{kind}_{man['prefix']}"
    if exe.exists():
        return exe
    out.mkdir(parents=True, exist_ok=True)
    (out / "ahrs_layout.h").write_text(layout)
    cmd = [compiler, *flags, f"-I{out}", f"-I{FUZZ_DIR}", f"-I{gen_dir}", str(harness), str(src),
           "-o", str(exe) + ".tmp", "-lm"]
    r = subprocess.run(cmd, capture_output=True, text=True)
    if r.returncode != 0:
        raise HardenError(f"building the {kind} harness for {gen_dir} failed:\n{' '.join(cmd)}\n{r.stderr}")
    os.replace(str(exe) + ".tmp", exe)
    return exe
