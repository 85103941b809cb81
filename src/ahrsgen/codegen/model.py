"""The contract every filter implements, and the parameter declarations it is configured by.

A filter is a folder (src/ahrsgen/filters/<name>/ for the built-ins, anywhere for a user filter:
see src/ahrsgen/filters/__init__.py and docs/your_own_filter.md):
  defaults.toml   [filter] title/source, [params.<name>] default/min/max/unit/doc (or choices)
  model.py        class Model(FilterModel): state fields, symbolic kernels, step partial
  reference.py    class Reference: independent NumPy implementation, same status bits
  step.c.j2       the body of <prefix>_step after the common input checks (Jinja partial)

Parameters shared by all filters for input checking (dt_max, gyro_max, accel/mag norm
bounds) are declared once here; a filter's defaults.toml may override their defaults.
"""
from __future__ import annotations

from ahrsgen.constants import use
from ahrsgen.errors import ConfigError  # noqa: F401  (raised here; callers import it from here too)
import math
from dataclasses import dataclass, field
from typing import Any

import casadi as ca


@dataclass
class Param:
    name: str
    default: Any
    doc: str = ""
    unit: str = ""
    min: float | None = None
    max: float | None = None
    min_exclusive: bool = False
    max_exclusive: bool = False
    choices: list | None = None

    @property
    def type(self) -> str:
        if isinstance(self.default, bool):
            return "bool"
        if isinstance(self.default, int):
            return "int"
        if isinstance(self.default, float):
            return "float"
        return "str"

    def range_text(self) -> str:
        if self.choices:
            return "one of " + ", ".join(repr(c) for c in self.choices)
        if self.type == "bool":
            return "true or false"
        lo = "-inf" if self.min is None else repr(self.min)
        hi = "inf" if self.max is None else repr(self.max)
        return f"{'(' if self.min_exclusive or self.min is None else '['}{lo}, {hi}{')' if self.max_exclusive or self.max is None else ']'}"

    def coerce(self, value, source: str = "") -> Any:
        """Check and convert a value (from TOML or a --set string); raise ConfigError."""
        where = f" ({source})" if source else ""
        t = self.type
        if isinstance(value, str) and t != "str":
            value = _parse_text(value)
        if t == "bool":
            if not isinstance(value, bool):
                raise ConfigError(f"parameter '{self.name}' = {value!r}{where} must be true or false")
            return value
        if t == "str":
            if not isinstance(value, str) or (self.choices and value not in self.choices):
                raise ConfigError(f"parameter '{self.name}' = {value!r}{where} must be {self.range_text()}")
            return value
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ConfigError(f"parameter '{self.name}' = {value!r}{where} must be a number in {self.range_text()}")
        if t == "int":
            if float(value) != int(value):
                raise ConfigError(f"parameter '{self.name}' = {value!r}{where} must be an integer in {self.range_text()}")
            value = int(value)
        else:
            value = float(value)
        if not math.isfinite(value):
            raise ConfigError(f"parameter '{self.name}' = {value!r}{where} must be finite, in {self.range_text()}")
        bad = ((self.min is not None and (value < self.min or (self.min_exclusive and value == self.min)))
               or (self.max is not None and (value > self.max or (self.max_exclusive and value == self.max))))
        if bad:
            raise ConfigError(f"parameter '{self.name}' = {value!r}{where} is out of range: allowed {self.range_text()}")
        return value


def _parse_text(text: str):
    low = text.strip().lower()
    if low in ("true", "false"):
        return low == "true"
    try:
        return int(low)
    except ValueError:
        pass
    try:
        return float(low)
    except ValueError:
        return text


def param_from_toml(name: str, spec: dict) -> Param:
    known = {"default", "doc", "unit", "min", "max", "min_exclusive", "max_exclusive", "choices"}
    extra = set(spec) - known
    if extra or "default" not in spec:
        raise ConfigError(f"defaults.toml: [params.{name}] needs 'default' and only {sorted(known)}; got {sorted(spec)}")
    return Param(name=name, **spec)


# Input checks shared by every filter (the sensor they concern in the key).
COMMON_PARAMS = {
    None: [
        Param("dt_max", 0.5, "largest dt a step accepts; larger is refused (DT_TOO_LARGE)", "s", 0.0, 10.0, True),
        Param("gyro_max", 70.0, "largest gyro component accepted; larger is refused (GYRO_RANGE)", "rad/s", 0.0, 1e4, True),
    ],
    "accel": [
        Param("accel_min_norm", 0.5, "accelerometer norm below this skips its correction (ACCEL_ZERO)", "m/s^2", 0.0, 100.0),
        Param("accel_max", 2000.0, "accelerometer component above this skips its correction (ACCEL_RANGE)", "m/s^2", 0.0, 1e6, True),
    ],
    "mag": [
        Param("mag_min_norm", 1e-6, "magnetometer norm below this skips its correction (MAG_ZERO)", "field unit", 0.0, 1e6),
        Param("mag_max", 1e6, "magnetometer component above this skips its correction (MAG_RANGE)", "field unit", 0.0, 1e12, True),
    ],
    "gps": [
        Param("gps_vel_max", 500.0, "GPS velocity component above this: the sample is ignored (GPS_RANGE)", "m/s", 0.0, 1e4, True),
    ],
}


@dataclass
class StateField:
    """One member of the generated state struct."""
    name: str
    size: int
    doc: str
    init: Any = 0.0            # scalar (fill) or list of `size` values
    ctype: str = "real"       # "real" (float/double per build) or "uint32"

    def init_values(self) -> list:
        if isinstance(self.init, (list, tuple)):
            if len(self.init) != self.size:
                raise ValueError(f"state field {self.name}: init has {len(self.init)} values, size is {self.size}")
            return list(self.init)
        return [self.init] * self.size


@dataclass
class KernelSpec:
    name: str
    function: ca.Function
    doc: str
    flags: tuple = ()     # inputs holding 0 or 1: emitted as bool (emit.emit's flags)
    noinline: bool = False  # GCC/clang: never inlined into its caller, so its stack frame does not add
    #                         to the caller's (a step calling several large kernels once each)
    early_writes: bool = False  # outputs stored as soon as computed, arrays declared restrict
    #                             (emit's early_writes): no output may overlap an input or output
    in_place: tuple = ()  # with early_writes: ((output, input), ...) pairs that may be one array (the
    #                       state updated in place; emit's in_place): no restrict, writes after reads


@dataclass
class FilterModel:
    """Base class of a filter's symbolic model. Subclasses fill in the hooks below."""
    params: dict
    sensors: tuple = ("accel", "mag", "gps")   # aiding sensors the step reads
    extra_status: list = field(default_factory=list)  # [(NAME, doc) or (NAME, doc, "info")]: bits from status.FILTER_BASE up

    # --- hooks -------------------------------------------------------------------------
    def state_fields(self) -> list[StateField]:
        raise NotImplementedError

    def kernels(self) -> list[KernelSpec]:
        """Symbolic kernels (build them with ahrsgen.codegen.emit.function)."""
        raise NotImplementedError

    def step_paths(self) -> dict[str, list[str]]:
        """Named paths through one step -> kernels they run, for the op-count report."""
        return {}

    def op_paths(self) -> dict[str, list[str]]:
        """step_paths as the op-count report (manifest "step_paths") counts them. Where the step
        runs the gyro over-range kernel only when it can change something (template context
        `gyro_quiet`, codegen/templates/gyro_recovery.c.j2: a gyro component near its range, a
        plateau run counting or a recovery under way), that kernel is counted on a path of its
        own rather than on every path."""
        paths = self.step_paths()
        if not self.template_context().get("gyro_quiet") or \
                not any("gyro_recovery" in ks for ks in paths.values()):
            return paths
        out = {n: [k for k in ks if k != "gyro_recovery"] for n, ks in paths.items()}
        out["gyro near its range (extra)"] = ["gyro_recovery"]
        return out

    def template_context(self) -> dict:
        """Extra values for the step partial (sizes, flags)."""
        return {}

    def stability_warnings(self) -> list[str]:
        """One line per combination of parameter values (each inside its declared range) that
        makes the filter diverge: `generate` and `validate` print them; `validate` then reads a
        disagreement as an unstable configuration rather than a code-generation error."""
        return []

    def template_helpers(self) -> tuple[str, ...]:
        """src/ahrsgen/codegen/fastmath.py helpers that the filter's own template code calls (a float build
        with math = "fast" gets their C beside the kernels' helpers, written once)."""
        return ()

    def gyro_recovery_state(self) -> list:
        """The state fields of the gyro over-range handling (gyro_recovery_kernel's)."""
        return [StateField("recover_time", 1, "time left of the recovery after a clipped gyro sample, s", 0.0),
                StateField("gyro_prev", 3, "the previous gyro sample, rad/s (over-range plateau)", 0.0),
                StateField("gyro_repeats", 3, "times each gyro component has repeated its value at or above "
                           "gyro_plateau_rate (over-range plateau)", 0.0)]

    def gyro_recovery_kernel(self) -> KernelSpec:
        """The gyro over-range kernel a filter with gyro_full_scale, gyro_plateau_rate and
        clip_recovery_time parameters calls once per step (symbolic/aiding.gyro_plateau and
        gyro_recovery): clipped, the recovery timer, whether the step is recovering, and the
        plateau's state (gyro_recovery_state)."""
        from ahrsgen.codegen.emit import function
        from ahrsgen.symbolic import aiding
        g, prev, reps = ca.SX.sym("gyro", 3), ca.SX.sym("gyro_prev", 3), ca.SX.sym("gyro_repeats", 3)
        t, dt = ca.SX.sym("recover_time"), ca.SX.sym("dt")
        plateau, reps_new = aiding.gyro_plateau(g, prev, reps, min_rate=self.params["gyro_plateau_rate"])
        clipped, t_new, recovering = aiding.gyro_recovery(
            g, t, dt, full_scale=self.params["gyro_full_scale"], recovery_time=self.params["clip_recovery_time"],
            plateau=plateau)
        return KernelSpec("gyro_recovery", function(
            "gyro_recovery", {"gyro": g, "gyro_prev": prev, "gyro_repeats": reps, "recover_time": t, "dt": dt},
            {"clipped": clipped, "recover_time_new": t_new, "recovering": recovering,
             "gyro_repeats_new": reps_new}),
            "gyro over-range: a component at gyro_full_scale, or one at or above gyro_plateau_rate that "
            f"holds its value for {aiding.PLATEAU_SAMPLES} samples while the others change (clipped), sets the "
            "recovery timer to clip_recovery_time; recovering while more than half a step of it is left",
            flags=("clipped", "recovering"))

    def gyro_recovery_quiet(self) -> list[str]:
        """The parameters whose squares bound |gyro|^2 on a step where gyro_recovery_kernel can
        change nothing (codegen/templates/gyro_recovery.c.j2 then skips it; template context
        `gyro_quiet`): gyro_full_scale and gyro_plateau_rate, each unless 0 (off), the smaller
        alone when both are numbers; a runtime one (a symbol) is always listed, its 0 then failing
        the bound. Empty (both off): the kernel runs every step."""
        p = self.params
        names = [n for n in ("gyro_full_scale", "gyro_plateau_rate")
                 if not isinstance(p[n], (int, float)) or p[n] > 0]
        numbers = [n for n in names if isinstance(p[n], (int, float))]
        if len(numbers) == 2:
            return [min(numbers, key=lambda n: p[n])]
        return names

    def hard_iron_state(self, bias: bool = True) -> list:
        """The state fields of the hard-iron estimate (hard_iron_kernel's; docs/mekf.md "Hard
        iron"), the hard iron `mag_bias` itself first unless bias = False (a filter that always
        has it declares it)."""
        from ahrsgen.symbolic import aiding
        nc = aiding.HARD_IRON_NC
        return ([self.hard_iron_bias_field()] if bias else []) + [
            StateField("mag_cx", nc, "candidate field model [hard iron / B (3), norm / B, down component / B], "
                       "B the reference norm", 0.0),
            StateField("mag_cP", nc * nc, "its covariance (5x5, symmetric)",
                       [use(aiding.HARD_IRON_P0) ** 2 if i == j else 0.0 for j in range(nc) for i in range(nc)]),
            StateField("mag_c_ok", 1, "0: the candidate starts from the present model at the next fit; 1: "
                       "fitted; 2: its covariance reopens at the next fit (a new disturbance)", 0, "uint32"),
            StateField("mag_rlp", 4, "hard-iron residuals [present (2), candidate (2)] low-passed over "
                       f"{aiding.HARD_IRON_RES_TAU:g} s", 0.0),
            StateField("mag_rmean", 2, "the present residuals' mean over mag_bias_settle", 0.0),
            StateField("mag_e", 3, "mean squares: present, candidate, present less its mean", 0.0),
            StateField("mag_turn_time", 1, "time turning since the candidate started or switched, s (stops at 1e3)", 0.0),
            StateField("mag_suspect", 1, "1 while the candidate explains the field and the present model does not", 0, "uint32"),
        ]

    @staticmethod
    def hard_iron_bias_field() -> StateField:
        return StateField("mag_bias", 3, "magnetometer hard iron, body axes, the field's units (m - mag_bias is used)", 0.0)

    def hard_iron_kernel(self, *, refine, dip_angle: bool, noinline: bool = False) -> KernelSpec:
        """The hard-iron kernel (symbolic/aiding.hard_iron_step) a filter with the mag_bias_*
        parameters calls on a step with a magnetometer sample while the sensor turns: the
        candidate's fit, its bookkeeping and the switch, with flags `suspect` and `switched`.
        `refine`: the smallest change of a hard iron once one is found (the filter's norm
        tolerance); dip_angle: the filter's reference is [norm, dip angle], else [norm, sin dip];
        noinline: a call of its own (its frame then does not add to the caller's, where the caller's
        frame is the larger: adukf's step 512 -> 480 B worst case at -O2; mekf's already calls it from
        a helper of its own; qcf's step frame is the smaller, 360 B inlined and 480 B a call, but
        inlined it costs the every-step path 127 est. cycles at -Os, so qcf calls it too)."""
        from ahrsgen.codegen.emit import function
        from ahrsgen.symbolic import aiding
        nc = aiding.HARD_IRON_NC
        p = self.params
        ins = {"q": ca.SX.sym("q", 4), "mag": ca.SX.sym("mag", 3), "b": ca.SX.sym("b", 3), "ref": ca.SX.sym("ref", 2),
               "cx": ca.SX.sym("cx", nc), "cP": ca.SX.sym("cP", nc * nc), "fresh": ca.SX.sym("fresh"),
               "reopen": ca.SX.sym("reopen"), "rlp": ca.SX.sym("rlp", 4), "rmean": ca.SX.sym("rmean", 2),
               "e": ca.SX.sym("e", 3), "turn_time": ca.SX.sym("turn_time"), "dt": ca.SX.sym("dt")}
        outs = aiding.hard_iron_step(
            ins["q"], ins["mag"], ins["b"], ins["ref"], ins["cx"], ins["cP"], ins["fresh"], ins["reopen"], ins["rlp"], ins["rmean"],
            ins["e"], ins["turn_time"], ins["dt"], rw=p["mag_bias_rw"], noise=p["mag_bias_noise"],
            bias_max=p["mag_bias_max"], settle=p["mag_bias_settle"], th=p["mag_bias_th"], jump=p["mag_bias_jump"],
            refine=refine, dip_angle=dip_angle)
        return KernelSpec("hard_iron", function("hard_iron", ins, outs),
                          "hard iron while turning: the candidate field model's fit, its residuals' bookkeeping, "
                          "and the switch to it (flags suspect, switched)",
                          flags=("fresh", "reopen", "suspect", "switched"), noinline=noinline)
