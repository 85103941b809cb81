"""CPF: complementary + particle filter (Xu, Zhao, Luo 2021), symbolic model.

Per step (SPEC.md, CPF; reference.py spells out every equation):
  am angles      φ_a = atan2(−f_y, −f_z), θ_a = atan2(f_x, √(f_y²+f_z²)), ψ_m tilt-compensated
  gyro predict   q_g = normalise((I + dt/2 Ω(ω)) q_cf)                          (eq. 11)
  complementary  a = wrap(a_g + (1−k) wrap(a_am − a_g)), k = τ/(τ+dt)           (eqs. 7, 8)
  particles      x_i = normalise(x_i + ½ x_i ⊗ [0, ω dt + σ_p√dt n_i]), n_i ~ N(0, I₃)  (eqs. 9, 11;
                 faithful: normalise((I + dt/2 Ω(ω)) x_i + σ_p√dt/2 n_i), n_i ~ N(0, I₄), eq. 9's W)
  alignment      x_i ← −x_i where ⟨x_i, Y⟩ < 0 (q ≡ −q; Y = q_prev without an observation)
  likelihood     w_i ← w_i exp(4(⟨Y,x_i⟩ − c_max)/σ_o²), Y = q_cf                 (eqs. 12, 13)
  estimate       q = normalise(Σ w_i x_i), the weights kept unnormalised         (eqs. 14, 15)
The loops over particles, the weight normalisation, systematic resampling and the PRNG
(xoroshiro64**, ziggurat Gaussian; prng.py documents the exact semantics) are written in the
filter's templates (helpers.c.j2, step.c.j2) around these kernels.
"""
from __future__ import annotations

import math

import casadi as ca

from ahrsgen.codegen import fastmath
from ahrsgen.codegen.emit import function
from ahrsgen.filters.cpf.prng import ZIG_F, ZIG_K, ZIG_R, ZIG_W, seed_state
from ahrsgen.filters.cpf.reference import WEIGHT_SUM_MIN
from ahrsgen.codegen.model import FilterModel, KernelSpec, StateField
from ahrsgen.constants import Const, named
from ahrsgen.symbolic import attitude, quat

# the step keeps its previous estimate when the weighted mean's squared norm is below this
# fraction of the squared weight sum (the aligned particles cancel)
MEAN_NORM2_MIN = Const("MEAN_NORM2_MIN", 1e-30)

FILTER_STATUS = [
    ("WEIGHTS_RESET", "particle weights summed to zero (underflow or corrupted state): reset to 1/N"),
    ("NOT_INITIALISED", "no usable accelerometer sample yet to initialise from; state unchanged", "info"),
]


def transition(q, w, dt):
    """Eq. 11: (I + dt/2 Ω(ω)) q, the first-order quaternion update q + dt/2 q ⊗ [0, ω]."""
    return q + 0.5 * dt * quat.qmul(q, quat.vec(0, w[0], w[1], w[2]))


class Model(FilterModel):
    # `ahrsgen validate` in float: the same random numbers, but float rounding changes which
    # particles are resampled, so float and double are compared as estimators over several
    # particle-noise streams (src/ahrsgen/sim/stochastic.py), each stream a PRNG state:
    @staticmethod
    def random_state(stream: int) -> dict:
        """State fields that select particle-noise stream `stream` (the PRNG state seeded with it)."""
        return {"rng": seed_state(int(stream))}

    def __init__(self, params: dict):
        super().__init__(params, sensors=("accel", "mag"), extra_status=list(FILTER_STATUS))

    @property
    def n(self) -> int:
        return int(self.params["n_particles"])

    @property
    def noise_dim(self) -> int:
        """Normals per particle and prediction: 3 (rotation-vector noise, the default) or 4
        (faithful: the paper's additive quaternion noise W of eq. 9)."""
        return 4 if self.params["faithful"] else 3

    @property
    def mode(self) -> str:
        return self.params["mode"]

    def state_fields(self):
        n = self.n
        pf = self.mode != "complementary"
        fields = [
            StateField("q", 4, "attitude estimate, body->NED, [w x y z]", [1.0, 0.0, 0.0, 0.0]),
            StateField("q_cf", 4, "complementary filter output (the particle filter's observation)",
                       [1.0, 0.0, 0.0, 0.0]),
        ]
        if pf:
            fields += [
                StateField("particles", 4 * n, f"{n} particles, quaternions [w x y z] one after another "
                           "(drawn at initialisation)", 0.0),
                StateField("weights", n, "particle weights, normalised by weight_sum (eq. 14 deferred to their "
                           "next use)", named("1 / n_particles", 1.0 / n)),
                StateField("weight_sum", 1, "the weights' sum (their divisor): 1 after initialisation and "
                           "resampling", 1.0),
                StateField("ess", 1, "effective sample size weight_sum^2/sum(w^2) after the last update",
                           named("n_particles", float(n))),
                StateField("rng", 2, f"xoroshiro64** state (seeded from {self.params['seed']})",
                           seed_state(int(self.params["seed"])), "uint32"),
                StateField("scratch", n, "per-particle scratch: <x_i, Y> during a step, then the number of "
                           "copies of each particle while resampling (whole numbers)", 0.0),
                StateField("resample_count", 1, "number of resamplings so far (wraps)", 0, "uint32"),
            ]
        fields.append(StateField("initialised", 1, "1 once initialised from the accelerometer/magnetometer",
                                 0, "uint32"))
        return fields

    def kernels(self):
        p = self.params
        q = ca.SX.sym("q", 4)
        x = ca.SX.sym("x", 4)
        y = ca.SX.sym("y", 4)
        gyro = ca.SX.sym("gyro", 3)
        dt = ca.SX.sym("dt")
        f = ca.SX.sym("accel", 3)
        m = ca.SX.sym("mag", 3)
        roll = ca.SX.sym("roll")
        pitch = ca.SX.sym("pitch")
        rpy = ca.SX.sym("rpy", 3)
        am = ca.SX.sym("am", 3)
        noise = ca.SX.sym("noise", 4)
        nd = self.noise_dim
        pnoise = ca.SX.sym("noise", nd)
        hw = ca.SX.sym("hw", 3)
        sp = ca.SX.sym("sp")
        use_accel = ca.SX.sym("use_accel")
        use_mag = ca.SX.sym("use_mag")
        w = ca.SX.sym("w")
        cmax = ca.SX.sym("cmax")
        cdot = ca.SX.sym("c")
        acc = ca.SX.sym("acc", 4)
        ref = ca.SX.sym("ref", 4)

        r_a, p_a = attitude.tilt_angles(f)
        ks = [
            KernelSpec("tilt", function("tilt", {"accel": f}, {"roll": r_a, "pitch": p_a}),
                       "accelerometer roll and pitch (eqs. 1-2 in FRD/NED)"),
            KernelSpec("heading", function("heading", {"mag": m, "roll": roll, "pitch": pitch},
                                           {"yaw": attitude.tilt_compensated_heading(m, roll, pitch, p["declination"])}),
                       "tilt-compensated magnetic heading plus declination (eq. 3 in FRD/NED)"),
            KernelSpec("from_euler", function("from_euler", {"rpy": rpy},
                                              {"q": quat.from_euler(rpy[0], rpy[1], rpy[2])}),
                       "quaternion of Z-Y-X Euler angles [roll, pitch, yaw]"),
        ]
        if self.mode != "particle":
            g = dt / (p["tau"] + dt)                 # 1 - k, k = tau / (tau + dt)  (eq. 8)
            gains = [use_accel * g, use_accel * g, use_mag * g]
            mixed = [quat.wrap(rpy[i] + gains[i] * quat.wrap(am[i] - rpy[i])) for i in range(3)]
            ks += [
                KernelSpec("predict", function("predict", {"q": q, "gyro": gyro, "dt": dt},
                                               {"q_new": quat.qnormalize(transition(q, gyro, dt))}),
                           "gyro prediction by eq. 11, normalised"),
                KernelSpec("cf_mix", function("cf_mix", {"rpy": rpy, "am": am, "dt": dt, "use_accel": use_accel,
                                                         "use_mag": use_mag},
                                              {"q_cf": quat.from_euler(*mixed)}),
                           "complementary mix of gyro and accel/mag angles through wrapped differences (eqs. 7-8)"),
            ]
        if self.mode != "complementary":
            s_p = 0.5 * p["process_noise"] * ca.sqrt(dt)
            s_0 = 0.5 * p["init_spread"]
            d_xy = ca.dot(x, y)
            gain = 4.0 / (p["obs_noise"] * p["obs_noise"])
            if nd == 4:     # the paper's additive quaternion noise W (eq. 9), then eq. 11
                move = x + quat.qmul(x, quat.vec(0, hw[0], hw[1], hw[2])) + sp * pnoise
                move_doc = ("particle prediction: eq. 11 plus the paper's additive quaternion process noise "
                            "(eq. 9, four components; normalised after it by the normalize kernel)")
            else:           # the noise as a rotation vector added to the gyro increment (tangent space)
                d = [hw[k] + sp * pnoise[k] for k in range(3)]
                move = x + quat.qmul(x, quat.vec(0, d[0], d[1], d[2]))
                move_doc = ("particle prediction: eq. 11 with the process noise as a rotation-vector "
                            "perturbation of the increment, x + x (x) [0, dt/2 w + sp n] (normalised after "
                            "it by the normalize kernel)")
            ks += [
                KernelSpec("init_particle", function("init_particle", {"q": q, "noise": noise},
                                                     {"x": quat.qnormalize(q + s_0 * noise)}),
                           "initial particle: the first attitude plus quaternion noise, normalised"),
                KernelSpec("particle_scales",
                           function("particle_scales", {"gyro": gyro, "dt": dt},
                                    {"hw": 0.5 * dt * gyro, "sp": s_p}),
                           "once per step for every particle: half the rotation increment (dt/2 gyro, eq. 11) "
                           "and the process-noise std (eq. 9)"),
                KernelSpec("particle_move", function("particle_move", {"x": x, "hw": hw, "sp": sp, "noise": pnoise},
                                                     {"x_new": move}),
                           move_doc),
                KernelSpec("obs_dot", function("obs_dot", {"x": x, "y": y}, {"d": d_xy}),
                           "<x, Y>: cosine of half the angle between particle and observation, up to the "
                           "sign (q = -q; the step keeps each particle where it is >= 0)"),
                KernelSpec("log_likelihood", function("log_likelihood", {"d": cdot, "cmax": cmax},
                                                      {"t": (gain * 64.0 / math.log(2.0)) * (cdot - cmax)}),
                           "log of the Gaussian likelihood exp(-4(1-|<x,Y>|)/obs_noise^2) scaled by its maximum "
                           "(eq. 13), from d = |<x, Y>| (the particle in Y's hemisphere), in units of ln2/64: "
                           "t <= 0; the step multiplies the weight by 2^(t/64)"),
                KernelSpec("accumulate", function("accumulate", {"acc": acc, "w": w, "x": x},
                                                  {"acc_new": acc + w * x}),
                           "weighted sum of the particles (eq. 15), each in the observation's hemisphere"),
                KernelSpec("normalize", function("normalize", {"acc": acc},
                                                 {"q": acc / ca.sqrt(ca.sumsqr(acc))}),
                           "normalised quaternion"),
            ]
        return ks

    def template_context(self):
        return {"n_particles": self.n, "mode": self.mode, "faithful": bool(self.params["faithful"]),
                "noise_dim": self.noise_dim,
                "ess_threshold": float(self.params["ess_threshold"]),
                "wsum_min": WEIGHT_SUM_MIN, "wsum_min_doc": "2^-20",
                "mean_norm2_min": MEAN_NORM2_MIN,
                "zig_kw": [(256 * k, w / 256.0) for k, w in zip(ZIG_K, ZIG_W)], "zig_f": ZIG_F, "zig_r": ZIG_R,
                "exp_nonpos_source": fastmath.exp_nonpos_source, "math_ln2": math.log(2.0)}

    def template_helpers(self):
        return () if self.mode == "complementary" else ("log",)   # the ziggurat's tail (helpers.c.j2)

    def step_paths(self):
        n = self.n
        cf = ["predict", "euler", "tilt", "heading", "cf_mix"]
        if self.mode == "complementary":
            return {"accel+mag": cf, "gyro only": ["predict"]}
        pf_pred = ["particle_scales"] + ["particle_move", "normalize"] * n
        pf_upd = ["obs_dot"] * n + ["log_likelihood"] * n
        est = ["accumulate"] * n + ["normalize"]
        if self.mode == "particle":
            return {"accel+mag (kernels)": ["tilt", "heading", "from_euler"] + pf_pred + pf_upd + est,
                    "gyro only (kernels)": pf_pred + est}
        return {"accel+mag (kernels)": cf + pf_pred + pf_upd + est,
                "gyro only (kernels)": ["predict"] + pf_pred + est}
