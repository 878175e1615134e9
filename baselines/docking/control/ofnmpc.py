"""Offset-free nonlinear MPC for docking ([OFNMPC] §3.2), built in CasADi.

The prediction model is the env's 4-DOF :class:`~auv_envs.core.hydrodynamics.NominalModel`
(from ``calibration.nominal_model``; no second copy of the dynamics), augmented
with a constant generalized disturbance ``d`` ([OFNMPC] eq. 12) and
discretised by one RK4 step per shooting interval ([OFNMPC] §3.4, multiple
shooting). The observer's estimates ``(x_hat, d_hat)`` are parameters.

Offset-free formulation ([OFNMPC] eqs. 13-16): the target state and input
``(x_s, u_s)`` are decision variables tied by equality constraints inside the
NLP::

    x_s = F(x_s, u_s, d_hat)          equilibrium of the augmented model
    (x_s, y_s, z_s, psi_s) = r        the docking point and heading

so no analytic steady state is needed; the stage cost penalises ``x_k - x_s``
and ``u_k - u_s``. With ``d_hat`` equal to the true constant disturbance the
closed loop settles at ``r`` with zero offset. (The pose part of ``x_s`` is
written as ``r`` itself, so the second condition holds by construction. A
state whose pose stays at ``r`` is at rest, so the velocity part of ``x_s`` is
zero and the equilibrium reduces to the four velocity rows of the model at
``(r, 0)``, ``f_nu(r, 0, u_s, d_hat) = 0``, with ``u_s`` the decision
variable; the pose rows, ``J(psi) 0``, vanish identically. Carrying four
fewer target variables through the horizon makes each solve cheaper than
with the velocity target as free variables, which the solver drove to zero
anyway.)

The optimal control problem solved each control step ([OFNMPC] eqs. 13-16,
with eq. 10's constraints softened), over ``N`` shooting intervals of ``t_s``
seconds, parameters ``(x_hat, d_hat, r)``::

    min   sum_{k=0}^{N-1} ( ||X_k - x_s||_Q^2 + ||U_k - u_s||_R^2 + rho_1 s_k + rho_2 s_k^2 )
          + ||X_N - x_s||_P^2
    over  X_0..X_N, U_0..U_{N-1}, u_s, s_0..s_{N-1}
    s.t.  X_0 = x_hat
          X_{k+1} = F(X_k, U_k, d_hat)                one RK4 step of the nominal model
          x_s = (r, 0),   f_nu(x_s, u_s, d_hat) = 0    target condition
          -tau_max <= U_k <= tau_max,   -tau_max <= u_s <= tau_max
          g(X_k) + s_k >= 0,   s_k >= 0                soft state constraints (below)

with ``Q = diag(state_weights)``, ``R = diag(input_weights / tau_max^2)``,
``P = terminal_scale Q`` and ``(rho_1, rho_2) = slack_weights``
(:class:`OFNMPCConfig`). The first input ``U_0`` is applied.

Constraints ([OFNMPC] eq. 10, Fig. 6): input limits (hard); soft, with one
slack per stage and an exact L1 penalty: the nose not behind the entrance
plane, the hull above the seabed, the nose inside an approach wedge opening
from the entrance (horizontal and vertical position constraints), a speed
envelope, and the field of view — every guide light inside the image with a
pixel margin, written bilinearly in the camera-frame coordinates
(``m <= f X/Z + c <= W - m`` times ``Z > 0``) so the constraint stays smooth.

Solver: FATROP (a structure-exploiting interior-point method for optimal
control problems, shipped with CasADi) through ``nlpsol`` on an ``SX`` graph
laid out stage by stage, warm-started with the previous solution shifted in
time by one control period; IPOPT on the same NLP is an option
(``OFNMPCConfig(solver="ipopt")``, primal-dual warm start). Measured on this
project's machine (``benchmarks/ofnmpc_speed.py --ipopt``, median CPU time per
``ofnmpc-ekf`` step, two runs), FATROP took about two thirds of IPOPT's time
(0.66-0.68, both uncompiled), and compiling the NLP's functions to C halved
FATROP's again (0.49-0.52). Compiling is the default:
the first controller of a given problem (horizon, weights, calibration)
generates C code and builds it once with the system compiler (about half a
minute to a minute at ``-O1``), and every later controller, in any process,
loads the cached library (:func:`compiled_nlpsol`). Without a C compiler the
controller warns and evaluates the same functions in CasADi's virtual machine;
``OFNMPCConfig(compile=False)`` asks for that directly. A failed solve (not converged
within ``max_iter``, or infeasible) does not stop the vehicle: the last
successful plan, shifted by the time elapsed since it was computed, is applied
instead, and the failure is counted (``failures``; the agents report it in
``stats()``).
"""

from __future__ import annotations

import contextlib
import dataclasses
import hashlib
import os
import shutil
import subprocess
import sys
import tempfile
import time
import warnings
from pathlib import Path

import casadi as ca
import numpy as np

try:
    import fcntl
except ImportError:  # not POSIX
    fcntl = None

from auv_envs.core.cache import host_cache
from baselines.docking.estimation.observers import N_INPUT, N_STATE, PSI, VisualObservationModel


@dataclasses.dataclass(frozen=True)
class OFNMPCConfig:
    """Tuning of the offset-free NMPC.

    Attributes:
        horizon: shooting intervals N ([OFNMPC]: N >= 20).
        shooting_interval: seconds per interval (one RK4 step each).
        state_weights: Q diagonal on ``x_k - x_s`` (x, y, z, psi, u, v, w, r).
        input_weights: R diagonal on ``(u_k - u_s) / thrust_limits``.
        terminal_scale: terminal weight ``P = terminal_scale * Q``.
        fov_margin_px: margin of the field-of-view constraint, pixels.
        nose_ahead_limit: the nose may not pass this far beyond the entrance plane, m.
        seabed_clearance: hull clearance above the seabed, m.
        wedge: approach wedge ``|y_nose|, |z_nose| <= w0 + slope * (-x_nose)``
            as ``(w0, slope)``; ``None`` disables it.
        speed_limits: envelope on the horizontal speed ``sqrt(u^2 + v^2)``, on
            ``|w|`` and on ``|r|`` (m/s, m/s, rad/s).
        slack_weights: exact L1 and quadratic penalty on the soft-constraint slack.
        max_iter: iteration cap per control step.
        solver: ``"fatrop"`` (structure-exploiting interior point, default) or
            ``"ipopt"``; both solve the same NLP.
        tol, mu_init: solver tolerance and initial barrier parameter.
        compile: generate C code for the NLP's functions and derivatives and
            compile it with the system C compiler, once per problem (cached
            across processes, see :func:`compiled_nlpsol`); about twice as
            fast per step and the same iterates. Without a compiler it warns and
            evaluates in CasADi's virtual machine (``False``: always do that).
        compile_flags: compiler optimisation flags.
        max_distance: an estimate farther than this from the station (m) is not
            sent to the solver (FATROP does not return on positions near 10^8 m);
            the step counts as a failed solve and takes the fallback.
    """

    horizon: int = 20
    shooting_interval: float = 0.25
    state_weights: tuple[float, ...] = (1.0, 3.0, 3.0, 5.0, 1.0, 1.0, 1.0, 1.0)
    input_weights: tuple[float, float, float, float] = (0.5, 0.5, 0.5, 0.5)
    terminal_scale: float = 10.0
    fov_margin_px: float | None = 20.0
    nose_ahead_limit: float = 0.05
    seabed_clearance: float = 0.3
    wedge: tuple[float, float] | None = (0.1, 0.35)
    speed_limits: tuple[float, float, float] = (0.6, 0.3, 0.2)
    slack_weights: tuple[float, float] = (1e3, 1e3)
    max_iter: int = 60
    solver: str = "fatrop"
    tol: float = 1e-6
    mu_init: float = 1e-3
    compile: bool = True
    compile_flags: tuple[str, ...] = ("-O1",)
    max_distance: float = 1000.0

    def __post_init__(self):
        if self.horizon < 1 or self.shooting_interval <= 0:
            raise ValueError("horizon must be >= 1 and shooting_interval positive")


#: The functions an ``nlpsol`` oracle needs from a compiled library.
_NLP_FUNCTIONS = ("nlp_f", "nlp_g", "nlp_grad", "nlp_grad_f", "nlp_jac_g", "nlp_hess_l")


def cache_dir() -> Path:
    """Where this host's compiled solver libraries are kept: ``<user cache>/casadi/<host
    key>`` (:func:`auv_envs.core.cache.host_cache`: a node sharing the cache never loads
    a library built for other CPU features)."""
    return host_cache("casadi")


def compiled_nlpsol(name: str, plugin: str, solver: ca.Function, options: dict,
                    flags=("-O1",)) -> ca.Function:
    """The same NLP solver with its functions compiled to C (CasADi code generation).

    The NLP (``solver``'s oracle) and the derivative functions the solver
    evaluates are generated with ``casadi.CodeGenerator``, compiled into a
    shared library and loaded with ``nlpsol(name, plugin, library)``. The
    library is cached under :func:`cache_dir`, keyed by the serialised NLP,
    the CasADi version and the flags, so each problem compiles once: processes
    that need the same library at the same time (``evaluate.py``'s workers,
    ``pytest -n``) take a lock on it, and all but the first find it built.

    Raises:
        RuntimeError: no C compiler on the ``PATH`` or the compiler failed.
    """
    oracle = solver.oracle()
    key = hashlib.sha256(
        "|".join([oracle.serialize(), plugin, ca.__version__, *flags]).encode()
    ).hexdigest()[:20]
    library = cache_dir() / f"{name}_{key}.so"
    if not library.exists():
        compiler = shutil.which(os.environ.get("CC", "cc")) or shutil.which("gcc")
        if compiler is None:
            raise RuntimeError("no C compiler found (set CC)")
        library.parent.mkdir(parents=True, exist_ok=True)
        with _exclusive(library.with_suffix(".lock")):
            if not library.exists():  # not built by another process while we waited
                _build_library(name, oracle, solver, compiler, flags, library)
    return ca.nlpsol(name, plugin, str(library), options)


@contextlib.contextmanager
def _exclusive(path: Path):
    """Hold an exclusive advisory lock on ``path`` (POSIX ``flock``; released by the OS
    if the process dies). Where ``fcntl`` does not exist the block runs unlocked: the
    atomic rename in :func:`_build_library` still keeps a half-written library out of
    sight, two processes may merely both compile."""
    if fcntl is None:
        yield
        return
    with open(path, "a") as handle:
        fcntl.flock(handle, fcntl.LOCK_EX)
        try:
            yield
        finally:
            fcntl.flock(handle, fcntl.LOCK_UN)


def _build_library(name: str, oracle: ca.Function, solver: ca.Function, compiler: str,
                   flags, library: Path) -> None:
    """Generate the NLP's C code and compile it into ``library`` (atomically)."""
    print(f"auv_envs: compiling the {name} NLP to C once ({' '.join(flags)}, about a minute); "
          f"cached as {library}", file=sys.stderr, flush=True)
    generator = ca.CodeGenerator(f"{name}.c", {"with_header": False})
    generator.add(oracle)
    for function in _NLP_FUNCTIONS:
        generator.add(solver.get_function(function))
    with tempfile.TemporaryDirectory(dir=library.parent) as tmp:
        source, built = Path(tmp) / f"{name}.c", Path(tmp) / "lib.so"
        source.write_text(generator.dump())
        run = subprocess.run(
            [compiler, *flags, "-fPIC", "-shared", str(source), "-o", str(built), "-lm"],
            capture_output=True, text=True, check=False,
        )
        if run.returncode != 0:
            raise RuntimeError(f"compiling {name} failed: {run.stderr[-2000:]}")
        os.replace(built, library)  # atomic: a reader never sees half a file


@dataclasses.dataclass(frozen=True)
class NMPCResult:
    """One control step: the input to apply and how it was obtained."""

    tau: np.ndarray
    success: bool
    fallback: bool
    solve_time: float
    iterations: int
    status: str


class OffsetFreeNMPC:
    """[OFNMPC]'s OFNMPC on the env's nominal model.

    Args:
        calibration: the docking env's ``calibration``.
        config: :class:`OFNMPCConfig`.
        nominal_model: prediction model (default ``calibration.nominal_model``).

    Attributes:
        reference: ``r = (x, y, z, psi)`` of the CG, a parameter of the NLP;
            the docking point (``calibration.target_position``, heading 0) by
            default. Another set point (e.g. station keeping in front of the
            entrance) can be assigned between solves.
    """

    def __init__(self, calibration, config: OFNMPCConfig | None = None, nominal_model=None):
        self.config = config or OFNMPCConfig()
        self.calibration = calibration
        self.model = nominal_model or calibration.nominal_model
        self.limits = np.asarray(calibration.thrust_limits, dtype=float)
        self.reference = np.concatenate([np.asarray(calibration.target_position, float), [0.0]])
        self._visual = VisualObservationModel(calibration)
        self._build()
        self.reset()

    # ------------------------------------------------------------------ NLP
    # Stage-wise layout, what FATROP's structure detection needs (IPOPT does
    # not care): stage k holds chi_k = (X_k, u_s) and v_k = (U_k, s_k), where
    # the target input u_s is carried unchanged along the horizon
    # (chi_{k+1}[8:] = chi_k[8:]). x_s = (r, 0): the reference pose at rest,
    # so H x_s = r holds by construction, and the equilibrium (the velocity
    # rows of the model at x_s) is imposed once, at stage 0.
    def _build(self) -> None:
        cfg = self.config
        n, ts = cfg.horizon, cfg.shooting_interval
        nx, nu = N_STATE + N_INPUT, N_INPUT + 1
        chi = [ca.SX.sym(f"chi{k}", nx) for k in range(n + 1)]
        v = [ca.SX.sym(f"v{k}", nu) for k in range(n)]
        x0 = ca.SX.sym("x0", N_STATE)
        d = ca.SX.sym("d", N_INPUT)
        ref = ca.SX.sym("ref", 4)

        xk, uk = ca.SX.sym("xk", N_STATE), ca.SX.sym("uk", N_INPUT)
        step = ca.Function("rk4", [xk, uk, d], [self.model.step(xk, uk, ts, d=d, ops=ca)])
        soft = ca.Function("soft", [xk], [self._soft_constraints(xk)])
        q = ca.diag(ca.DM(cfg.state_weights))
        r = ca.diag(ca.DM(np.asarray(cfg.input_weights) / self.limits**2))
        l1, l2 = cfg.slack_weights

        cost, g, lbg, ubg, equality = 0, [], [], [], []

        def add(expr, lo, hi):
            g.append(expr)
            lbg.extend([lo] * expr.size1())
            ubg.extend([hi] * expr.size1())
            equality.extend([lo == hi] * expr.size1())

        def split(c):
            return c[:N_STATE], ca.vertcat(ref, ca.SX.zeros(4)), c[N_STATE:]

        for k in range(n):
            x, xs, us = split(chi[k])
            u, s = v[k][:N_INPUT], v[k][N_INPUT]
            dx, du = x - xs, u - us
            cost += ca.bilin(q, dx, dx) + ca.bilin(r, du, du) + l1 * s + l2 * s**2
            add(chi[k + 1] - ca.vertcat(step(x, u, d), chi[k][N_STATE:]), 0.0, 0.0)
            if k == 0:
                add(x - x0, 0.0, 0.0)
                # Target condition: x_s = (r, 0) is an equilibrium (velocity rows).
                add(ca.vertcat(*self.model.derivatives(xs, us, d, ops=ca)[4:]), 0.0, 0.0)
            add(soft(x) + s, 0.0, np.inf)
        x, xs, _ = split(chi[n])
        cost += cfg.terminal_scale * ca.bilin(q, x - xs, x - xs)

        decision = ca.vertcat(*[e for k in range(n) for e in (chi[k], v[k])], chi[n])
        nlp = {"x": decision, "p": ca.vertcat(x0, d, ref), "f": cost, "g": ca.vertcat(*g)}
        options = self._solver_options(equality)
        self._solver = ca.nlpsol("ofnmpc", cfg.solver, nlp, options)
        self.compiled = False
        if cfg.compile:
            try:
                self._solver = compiled_nlpsol("ofnmpc", cfg.solver, self._solver, options,
                                               cfg.compile_flags)
                self.compiled = True
            except RuntimeError as exc:
                warnings.warn(f"OFNMPC runs uncompiled: {exc}", RuntimeWarning, stacklevel=2)
        self._lbg, self._ubg = np.array(lbg), np.array(ubg)

        lbx, ubx = np.full(decision.size1(), -np.inf), np.full(decision.size1(), np.inf)
        stride = nx + nu
        for k in range(n):
            u0 = k * stride + nx
            lbx[u0 : u0 + N_INPUT], ubx[u0 : u0 + N_INPUT] = -self.limits, self.limits
            lbx[u0 + N_INPUT] = 0.0
        us0 = N_STATE
        lbx[us0 : us0 + N_INPUT], ubx[us0 : us0 + N_INPUT] = -self.limits, self.limits
        self._lbx, self._ubx = lbx, ubx
        self._stride, self._nx = stride, nx

    def _solver_options(self, equality: list[bool]) -> dict:
        cfg = self.config
        common = {"tol": cfg.tol, "max_iter": cfg.max_iter, "mu_init": cfg.mu_init,
                  "print_level": 0}
        if cfg.solver == "fatrop":
            return {"print_time": False, "structure_detection": "auto", "equality": equality,
                    "fatrop": common}
        if cfg.solver == "ipopt":
            return {"print_time": False, "ipopt": {
                **common, "sb": "yes", "warm_start_init_point": "yes",
                "warm_start_bound_push": 1e-6, "warm_start_mult_bound_push": 1e-6}}
        raise ValueError(f"unknown NLP solver {cfg.solver!r}; valid: 'fatrop', 'ipopt'")

    def _soft_constraints(self, x):
        """Rows that must be >= 0 (slack added) at one predicted state; roll = pitch = 0."""
        cfg, cal = self.config, self.calibration
        nose = cal.nose_offset
        x_n = x[0] + nose * ca.cos(x[PSI])
        y_n = x[1] + nose * ca.sin(x[PSI])
        z_n = x[2]
        half_height = cal.nominal_params.diameter / 2.0
        rows = [
            cfg.nose_ahead_limit - x_n,
            x[2] - half_height - cfg.seabed_clearance - cal.seabed_z,
        ]
        if cfg.wedge is not None:
            w0, slope = cfg.wedge
            width = w0 + slope * (-x_n)
            rows += [width - y_n, width + y_n, width - z_n, width + z_n]
        horizontal, heave, yaw_rate = cfg.speed_limits
        rows += [
            horizontal**2 - x[4] ** 2 - x[5] ** 2,
            heave - x[6], heave + x[6], yaw_rate - x[7], yaw_rate + x[7],
        ]
        if cfg.fov_margin_px is None:
            return ca.vertcat(*rows)
        k = cal.intrinsics
        m = cfg.fov_margin_px
        a_lo, a_hi = (m - k.cx) / k.fx, (k.width - m - k.cx) / k.fx
        b_lo, b_hi = (m - k.cy) / k.fy, (k.height - m - k.cy) / k.fy
        pts = self._visual.camera_points_expr(x, 0.0, 0.0)
        for i in range(self._visual.n_lights):
            xc, yc, zc = pts[0, i], pts[1, i], pts[2, i]
            rows += [xc - a_lo * zc, a_hi * zc - xc, yc - b_lo * zc, b_hi * zc - yc]
        return ca.vertcat(*rows)

    # ------------------------------------------------------------------ runtime
    def reset(self) -> None:
        """Forget the warm start, the stored plan and the counters (new episode)."""
        self.failures = 0
        self.solves = 0
        self.solve_times: list[float] = []
        self._solution = None  # last successful primal solution
        self._lam = None  # and its multipliers (IPOPT warm start)
        self._age = 0.0  # seconds since that solution was computed

    def solve(self, state, disturbance) -> NMPCResult:
        """The input for the current estimate: first move of the optimal plan, or the fallback.

        Args:
            state: estimated ``(x, y, z, psi, u, v, w, r)``.
            disturbance: estimated generalized disturbance ``d`` (4).
        """
        state = np.asarray(state, dtype=float)
        disturbance = np.asarray(disturbance, dtype=float)
        if state.shape != (N_STATE,) or disturbance.shape != (N_INPUT,):
            raise ValueError(f"OFNMPC needs a state ({N_STATE},) and a disturbance ({N_INPUT},)")
        if not (np.isfinite(state).all() and np.isfinite(disturbance).all()):
            raise ValueError("OFNMPC got a non-finite state or disturbance estimate")
        if np.linalg.norm(state[:3]) > self.config.max_distance:
            return self._failed(0.0, -1, "estimate beyond max_distance")
        guess = self._warm_start(state)
        p = np.concatenate([state, disturbance, self.reference])
        args = dict(x0=guess, p=p, lbx=self._lbx, ubx=self._ubx, lbg=self._lbg, ubg=self._ubg)
        if self._lam is not None and self.config.solver == "ipopt":
            # IPOPT's warm start uses the last multipliers (FATROP takes a primal guess).
            args.update(lam_x0=self._lam[0], lam_g0=self._lam[1])
        start = time.perf_counter()
        sol = self._solver(**args)
        elapsed = time.perf_counter() - start
        stats = self._solver.stats()
        iterations, status = int(stats.get("iter_count", -1)), str(stats["return_status"])
        if not stats["success"]:
            return self._failed(elapsed, iterations, status)
        self.solves += 1
        self.solve_times.append(elapsed)
        self._solution = np.asarray(sol["x"]).ravel()
        self._lam = (np.asarray(sol["lam_x"]).ravel(), np.asarray(sol["lam_g"]).ravel())
        self._age = self.calibration.control_period
        tau = self._inputs(self._solution)[0]
        return NMPCResult(tau=np.clip(tau, -self.limits, self.limits), success=True,
                          fallback=False, solve_time=elapsed, iterations=iterations,
                          status=status)

    def _failed(self, elapsed: float, iterations: int, status: str) -> NMPCResult:
        """A step without a solution: count it and apply the stored plan's next input."""
        self.solves += 1
        self.solve_times.append(elapsed)
        self.failures += 1
        tau = self._fallback()
        self._age += self.calibration.control_period
        return NMPCResult(tau=np.clip(tau, -self.limits, self.limits), success=False,
                          fallback=True, solve_time=elapsed, iterations=iterations,
                          status=status)

    def last_plan(self) -> tuple[np.ndarray, np.ndarray] | None:
        """The last successful solution: ``(chi (N + 1, nx), tau (N, 4))``, the stages'
        decision states and the planned generalized forces; None before the first."""
        if self._solution is None:
            return None
        chi, _ = self._stages(self._solution)
        return chi, self._inputs(self._solution)

    def _stages(self, solution: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(chi (N + 1, nx), v (N, nu))`` of a decision vector."""
        n = self.config.horizon
        body = solution[: n * self._stride].reshape(n, self._stride)
        chi = np.vstack([body[:, : self._nx], solution[n * self._stride :]])
        return chi, body[:, self._nx :]

    def _inputs(self, solution: np.ndarray) -> np.ndarray:
        return self._stages(solution)[1][:, :N_INPUT]

    def _fallback(self) -> np.ndarray:
        """The last successful plan shifted by the time since it was computed; zero without one."""
        if self._solution is None:
            return np.zeros(N_INPUT)
        index = min(int(self._age / self.config.shooting_interval), self.config.horizon - 1)
        return self._inputs(self._solution)[index].copy()

    def _warm_start(self, state: np.ndarray) -> np.ndarray:
        """Initial guess: the last plan shifted in time by its age, else the state held."""
        n, ts = self.config.horizon, self.config.shooting_interval
        if self._solution is None:
            chi = np.concatenate([state, np.zeros(N_INPUT)])
            stage = np.concatenate([chi, np.zeros(N_INPUT + 1)])
            return np.concatenate([np.tile(stage, n), chi])
        chi, v = self._stages(self._solution)
        if self._age > 0.0:
            nodes = np.arange(n + 1) * ts
            shifted = np.minimum(nodes + self._age, nodes[-1])
            chi = np.column_stack([np.interp(shifted, nodes, col) for col in chi.T])
            v = v[np.minimum((shifted[:-1] / ts).astype(int), n - 1)]
        chi[0, :N_STATE] = state
        return np.concatenate([np.hstack([chi[:-1], v]).ravel(), chi[-1]])

    def planned_states(self) -> np.ndarray | None:
        """(N + 1, 8) predicted states of the last successful solve (for plots)."""
        if self._solution is None:
            return None
        return self._stages(self._solution)[0][:, :N_STATE].copy()
