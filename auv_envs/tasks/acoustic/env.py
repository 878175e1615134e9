"""Acoustic tracking of an underwater manipulator's end effector [GMPHD].

``auv_envs/AcousticTracking-v2``: an acoustic source on the end effector of a
6-DOF arm, carried through a 300 m x 300 m tank by a neutrally buoyant
carrier and disturbed by the current, is heard by eight hydrophone nodes. The
agent estimates the end effector's position from the multi-band detection
sets (:mod:`auv_envs.core.acoustics`). The episode is
:mod:`auv_envs.tasks.acoustic.transition` (which also says why the physics
runs in blocks of sample periods on the CPU); this module is its task on the CPU,
which the one Gymnasium env runs.
"""

from __future__ import annotations

import copy
import math

import numpy as np

from auv_envs.core import difficulty as levels
from auv_envs.core.acoustics import (
    AcousticConfig,
)
from auv_envs.core.env import (
    CPUTask,
    ShellEpisode,
    check_image_size,
)
from auv_envs.tasks.acoustic import transition
from auv_envs.tasks.acoustic.bound import EpisodeRecord, MotionPrior, bound_rmse
from auv_envs.tasks.acoustic.config import (  # noqa: F401  (the names' home before the config)
    HARD_ACOUSTICS,
    OBS_MODES,
    PAPER_ACOUSTICS,
    PLANNERS,
    PRESETS,
    TRAJECTORIES,
    AcousticCalibration,
    AcousticTrackingConfig,
    params,
)
from auv_envs.tasks.acoustic.plant import (  # noqa: F401  (the names' home before the plant)
    ARM_JOINTS,
    CARRIER_JOINTS,
    INTEGRATORS,
    AcousticPhysics,
    build_tank_model,
    compose_tank_model,
)

#: Seconds of the end effector's path that ``render()`` draws, and of estimates in its close-up.
RENDER_TRAIL = 10.0
RENDER_CLOSEUP = 2.0




class AcousticTrackingTask(CPUTask):
    """Track an underwater arm's end effector with an 8-node hydrophone array [GMPHD].

    **Description.** A 300 m x 300 m x 30 m tank (tank frame: origin at a
    surface corner, z up) holds eight hydrophone nodes on its walls. A 6-DOF
    manipulator rides a neutrally buoyant carrier that follows a route of
    straight segments, curves and pauses; its joints sweep slowly about a
    nominal posture, and the current (MuJoCo's fluid model, with the current
    as ``wind``) pushes both. The acoustic source on the end effector is
    heard in Q = 10 sub-bands at fs = 100 Hz; per band and period the array
    reports a set of detections (TDOAs against node 1, per-node azimuth and
    elevation) with band-dependent noise and misses, multipath ghosts from
    the surface and the bottom, Poisson false alarms and clock offsets
    (:mod:`auv_envs.core.acoustics` documents the model). With
    ``AcousticConfig.flow_noise_level`` the current generators' flow noise
    lowers every band's SNR with the current's speed.

    **Action space.** ``Box([0, 0, -30], [300, 300, 0], (3,), float32)`` (the tank): the
    agent's estimate of the end effector's position (tank frame) at the time of the latest
    observation. Finite values outside the tank are clipped; NaN, inf and non-numbers raise
    ``ValueError``.

    =====  ========================================================  ====  ====  ===================
    index  action                                                    min   max   unit
    =====  ========================================================  ====  ====  ===================
    0      estimated x of the end effector, tank frame               0     300   m
    1      estimated y of the end effector                           0     300   m
    2      estimated z of the end effector (surface z = 0)           -30   0     m
    =====  ========================================================  ====  ====  ===================

    **Observation space** (``obs_mode``). Tank frame.

    ``state``: ``Box(-inf, inf, (9,), float32)``, privileged (the ground truth, as in
    ``info``):

    =====  ============================================================================  ===========
    index  observation                                                                   unit
    =====  ============================================================================  ===========
    0      end effector (the source) x, tank frame (``info["true_position"]``)           m
    1      end effector y                                                                m
    2      end effector z                                                                m
    3      end-effector velocity x (``info["true_velocity"]``)                           m/s
    4      end-effector velocity y                                                       m/s
    5      end-effector velocity z                                                       m/s
    6      current (water velocity) x (``info["current"]``)                              m/s
    7      current y                                                                     m/s
    8      current z (always 0)                                                          m/s
    =====  ============================================================================  ===========

    ``measurements``: ``Dict``, one sample period's detection sets: Q bands (10 by default,
    band q centred at 20 + 10 q kHz: ``acoustic.band_centres``), each padded to K
    detections (``acoustic.max_detections``, 8 by default); nodes 1-8 (index 0-7), node 1
    the TDOA reference:

    =============  =========  =======  ===================================================  ========
    key            shape      dtype    observation                                          unit
    =============  =========  =======  ===================================================  ========
    ``tdoa``       (Q, K, 7)  float64  per band and detection, the time differences of      s
                                       arrival ``t_i - t_1`` of nodes 2-8 against node 1
    ``azimuth``    (Q, K, 8)  float64  per node, the horizontal direction to the source,    rad
                                       ``atan2(y - y_i, x - x_i)`` in [-pi, pi]
    ``elevation``  (Q, K, 8)  float64  per node, the angle between the upward vertical and  rad
                                       the line to the source, in [0, pi]
    ``mask``       (Q, K)     int8     ``MultiBinary((Q, K))``: 1 for a real detection, 0   -
                                       for padding (zeros)
    ``node_mask``  (8,)       int8     with node dropouts only                              -
                                       (``acoustic.node_dropout_rate`` > 0):
                                       ``MultiBinary((8,))``, 1 where the node works
    =============  =========  =======  ===================================================  ========

    Within a band the detections' order is random: which one is the source is
    not observable. An out node's azimuth and elevation columns, and the TDOA
    columns of the pairs it belongs to (all of them while node 1 is out), are
    zero and measure nothing.

    **Rewards** (each in ``info["reward_<term>"]``, summing to the reward):

    ============  =========================================================
    term          value
    ============  =========================================================
    ``estimate``  ``-min(e, error_clip) / error_clip``, ``e`` the Euclidean
                  estimation error (m); in [-1, 0]
    ============  =========================================================

    **Starting state.** ``trajectory="dynamic"``: the carrier starts at rest
    at a random point of its route area (x, y in [65, 265] m, z in [-20, -8]
    m) and follows a seeded route
    (:func:`~auv_envs.tasks.acoustic.transition.draw_route`); the arm's joints sweep
    sinusoidally about ``NOMINAL_POSTURE`` (amplitudes 0.1-0.35 rad for the
    first three joints, 0.05-0.2 rad for the wrist, periods 12-40 s).
    ``trajectory="static"``: the carrier holds the end effector at one of
    [GMPHD] Table 1's five points (``static_point``; drawn when None) in the
    nominal posture. The current
    (:class:`~auv_envs.tasks.acoustic.transition.Flow`) sweeps the
    ``disturbance`` level's speed range with a veering direction.

    **Episode end.** No terminal state; truncated after ``time_limit`` s
    (``time_limit * 100`` steps).

    **Info.** Every step: ``estimate_error`` (m; NaN at reset),
    ``running_rmse`` (m; NaN at reset), ``tracked`` (error within
    ``track_gate``), ``is_success`` (running RMSE within ``success_radius``),
    the reward term, ground truth for metrics (``true_position``,
    ``true_velocity``, ``current``, ``detection_origin`` (Q, K): -1 padding,
    0 source, 1 surface ghost, 2 bottom ghost, 3 false alarm; where the
    detections are drawn: not in ``state`` mode unless rendering or
    ``draw_detections``), ``time``; with node dropouts ``nodes_working``
    (likewise). At reset, with a sound-speed error,
    the episode's true ``sound_speed``. At the end ``episode_metrics``:
    ``rmse``, ``max_error``, ``error_bias`` (norm of the mean error),
    ``tfc``, ``tcfe`` ([GMPHD]'s entropy of the estimate's first differences
    in 1 cm bins, which also scores the source's own speed),
    ``tcfe_fluctuation`` (the same on second differences, 0 for the true
    motion), ``mean_ospa``, ``success``.

    **Arguments.**

    ====================  ================  ==================  ====================================
    argument              Type              Default             meaning
    ====================  ================  ==================  ====================================
    ``obs_mode``          str               ``"measurements"``  ``"state"``, ``"measurements"``
    ``disturbance``       str               ``"medium"``        current speeds ([GMPHD] §3.4):
                                                                ``"low"`` 0.05-0.15 m/s,
                                                                ``"medium"`` 0.16-0.30 m/s,
                                                                ``"high"`` 0.31-0.50 m/s
    ``trajectory``        str               ``"dynamic"``       ``"dynamic"`` or ``"static"``
    ``static_point``      int | None        ``None``            1-5 or None (drawn)
    ``time_limit``        float             ``60.0``            s
    ``acoustic``          AcousticConfig |  ``None``            :class:`AcousticConfig` (None: the
                          None                                  level's; at ``easy`` the documented
                                                                model, ``AcousticConfig()``)
    ``error_clip``        float             ``5.0``             m
    ``track_gate``        float             ``1.0``             m
    ``success_radius``    float             ``0.5``             m
    ``physics_substeps``  int               ``2``               physics steps per 0.01 s (v0: 1)
    ``integrator``        str               ``"euler"``         MuJoCo's integrator of the rig:
                                                                ``"euler"`` or ``"implicitfast"``
                                                                (v0's)
    ``noise_draws``       str               ``"kept"``          the measurement noise drawn for the
                                                                kept detections only (``"kept"``) or
                                                                first, for every path (``"all"``,
                                                                v0's random stream)
    ``draw_detections``   bool              ``False``           draw the detections in ``state``
                                                                mode too, so that its ``info`` has
                                                                ``detection_origin`` (v0 did);
                                                                ``measurements`` mode and rendering
                                                                always draw them
    ``planner``           str               ``"segments"``      the carrier's route: ``"segments"``
                                                                (drawn per segment, the same code on
                                                                NumPy and JAX) or ``"tabulated"``
                                                                (v0/v1's sequential planner)
    ``render_mode``       str | None        ``None``            ``"rgb_array"`` or None
    ``render_size``       tuple[int, int]   ``(640, 480)``      (W, H) of ``render()``, at least 8x8
    ``difficulty``        str               ``"easy"``          ``DEFAULT_LEVEL``: ``"easy"`` (the
                                                                release), ``"paper"``
                                                                (:data:`PAPER_ACOUSTICS`, calibrated
                                                                to [GMPHD]'s tank), ``"hard"``
                                                                (:data:`HARD_ACOUSTICS`); sets
                                                                ``acoustic`` when it is not given
                                                                (``docs/difficulty.md``)
    ====================  ================  ==================  ====================================

    **Bound.** ``trajectory_bound()``, right after ``reset()``: the posterior
    Cramér–Rao bound (m) on the episode's ``rmse`` from this environment's
    own motion and measurement models along its true trajectory
    (:mod:`auv_envs.tasks.acoustic.bound`; the leaderboard's ``pcrb`` row).

    **Rendering.** ``render_mode="rgb_array"``: a top view, a side view and a
    close-up of the tank with the nodes, the end effector's recent path, the
    latest estimate and the current detections' rays coloured by origin
    (:class:`auv_envs.tasks.acoustic.render.TankPlot`), drawn from the
    episode's record, so rendering changes no observation or reward (an env
    made with ``render_mode`` draws the detections it shows, in ``state`` mode
    too).

    **Version history.** v2: the route drawn per segment with every draw made
    (the same model, other episodes; v1 is ``planner="tabulated"``), so that
    the batched environment draws it with the same code. v1: the rig in two
    Euler steps a period, the measurement noise drawn for the kept detections
    only, no detections drawn in ``state`` mode unless rendered or asked for
    (the same models; v0 is
    ``integrator="implicitfast", physics_substeps=1, noise_draws="all",
    draw_detections=True``). v0: initial release. The changes and their
    measurements: ``CHANGELOG.md``.
    """

    metadata = {"render_modes": ["rgb_array"], "render_fps": 100}
    _closeables = ("_plot",)

    #: The contract the registry-driven tests read (see tests/conftest.py).
    obs_modes = OBS_MODES
    #: ``difficulty`` levels (:mod:`auv_envs.core.difficulty`): the acoustic measurement model.
    difficulty_presets = PRESETS
    transition = transition
    reward_terms = transition.REWARD_TERMS
    metric_keys = transition.STEP_METRICS

    def __init__(
        self,
        obs_mode: str = "measurements",
        disturbance: str = "medium",
        trajectory: str = "dynamic",
        static_point: int | None = None,
        time_limit: float = 60.0,
        acoustic: AcousticConfig | None = None,
        error_clip: float = 5.0,
        track_gate: float = 1.0,
        success_radius: float = 0.5,
        physics_substeps: int = 2,
        integrator: str = "euler",
        noise_draws: str = "kept",
        draw_detections: bool = False,
        planner: str = "segments",
        render_mode: str | None = None,
        render_size: tuple[int, int] = (640, 480),
        difficulty: str = levels.DEFAULT_LEVEL,
        **unknown,
    ):
        self._accept_arguments(
            unknown,
            obs_mode=obs_mode, disturbance=disturbance, trajectory=trajectory,
            static_point=static_point, time_limit=time_limit, acoustic=acoustic,
            error_clip=error_clip, track_gate=track_gate, success_radius=success_radius,
            physics_substeps=physics_substeps, integrator=integrator,
            noise_draws=noise_draws, draw_detections=draw_detections, planner=planner,
            render_mode=render_mode,
            render_size=render_size, difficulty=difficulty,
        )
        self._render_size = check_image_size(render_size, "render_size")
        self._init_kwargs["render_size"] = self._render_size
        if render_mode is not None and draw_detections is False:
            draw_detections = True  # a rendering env draws the detections it shows
        setup = params(self._configuration(AcousticTrackingConfig,
                                           draw_detections=draw_detections))
        #: What the configuration fixes (:class:`~auv_envs.tasks.acoustic.config.AcousticSetup`).
        self.setup = setup
        #: The difficulty level (:mod:`auv_envs.core.difficulty`).
        self.difficulty = difficulty
        self.obs_mode = obs_mode
        self.render_mode = render_mode
        self.disturbance = disturbance
        self.trajectory = trajectory
        self._static_point = static_point
        #: The composed model's text (:class:`~auv_envs.core.assets.MJCF`).
        self.model_source = setup.model_source
        self.physics = AcousticPhysics(setup.model, noise_draws=noise_draws)
        self.physics.substeps = physics_substeps
        self._plant = self.physics
        self._dt = setup.dt
        self._horizon = setup.max_episode_steps
        #: Step period, s (one env step).
        self.dt = self._dt
        #: Steps of an episode (it always runs to its ``time_limit``).
        self.max_episode_steps = self._horizon
        self._error_clip = float(error_clip)
        self._track_gate = float(track_gate)
        self._success_radius = float(success_radius)
        self.calibration = setup.calibration
        #: The transition's :class:`~auv_envs.tasks.acoustic.transition.AcousticParams`.
        self.params = setup.params
        self.action_space = setup.action_space
        self.observation_space = setup.observation_space
        self._episode = ShellEpisode()
        self._plot = None  # the TankPlot, built on the first render()

    # ------------------------------------------------------------------ episode hooks
    def _begin_episode(self, rng: np.random.Generator, options: dict | None):
        _, state, truth, obs, _ = transition.reset(self.params, self._backend(rng))
        self._episode = ShellEpisode(state, obs)
        extras = {}
        if self.calibration.config.sound_speed_error_std > 0:
            extras["sound_speed"] = state.plan.sound_speed
        return truth, extras

    def truth_now(self) -> dict:
        if self._episode.steps < 1:
            raise RuntimeError("no step taken yet: nothing to summarise")
        return {"k": self._episode.steps, "error": float("nan")}

    @property
    def plot(self):
        """The :class:`~auv_envs.tasks.acoustic.render.TankPlot` that draws ``render()``'s
        frames: built on the first render, None before it and after ``close()``."""
        return self._plot

    def render_frame(self) -> np.ndarray:
        """The tank as an (H, W, 3) uint8 frame (``render_mode="rgb_array"``).

        Drawn from the episode's own record (true positions, estimates and the
        current detections), so calling it changes no observation, reward, info
        or random draw. Before the first reset it draws the empty tank.
        """
        if self._plot is None:
            from auv_envs.tasks.acoustic.render import TankPlot  # matplotlib only when drawing

            self._plot = TankPlot(self.calibration, self._render_size,
                                  track_gate=self._track_gate, trail_seconds=RENDER_TRAIL,
                                  closeup_seconds=RENDER_CLOSEUP)
        state = self._episode.state
        if state is None:  # no episode yet
            return self._plot.frame()
        block = state.block
        k = state.steps
        j = k - block.start
        trail_steps = int(round(RENDER_TRAIL / self._dt))
        first = max(0, k - trail_steps)
        truths, estimates = state.truths, state.estimates
        trail = np.concatenate([truths[first:k], block.positions[j : j + 1]])
        m = block.measurements  # drawn whenever rendering
        mask = m.mask[j].ravel()
        n = self.calibration.array.n_nodes
        azimuth = m.azimuth[j].reshape(-1, n)[mask]
        elevation = m.elevation[j].reshape(-1, n)[mask]
        if block.nodes is not None:  # an out node draws no ray (its zeros are no measurement)
            azimuth[:, ~block.nodes[j]] = np.nan
            elevation[:, ~block.nodes[j]] = np.nan
        estimate, error, rmse = None, float("nan"), float("nan")
        if k:
            estimate = estimates[k - 1]
            error = float(np.linalg.norm(estimate - truths[k - 1]))
            rmse = math.sqrt(state.squared_error_sum / k)
        closeup_steps = int(round(RENDER_CLOSEUP / self._dt))
        return self._plot.frame(
            time=k * self._dt,
            trail=trail,
            estimate=estimate,
            estimate_trail=estimates[max(0, k - closeup_steps) : k],
            azimuth=azimuth,
            elevation=elevation,
            origin=m.origin[j].ravel()[mask],
            error=error,
            rmse=rmse,
        )

    def observe(self, truth: dict):
        return self._episode.obs  # the transition's

    def step_info(self, truth: dict) -> dict:
        return transition.info(self.params, self._episode.state, truth)

    def episode_record(self) -> EpisodeRecord:
        """The whole episode's truth and realised nuisance, for the bound
        (:class:`~auv_envs.tasks.acoustic.bound.EpisodeRecord`): the true positions at
        the steps the episode scores, the current, the true sound speed, the emission
        positions heard (with propagation delay), the band fades and the node states.

        Plays the episode out on a copy (its generator included), so this episode's
        observations and draws are unchanged. Call it right after ``reset()``.

        Raises:
          RuntimeError: before ``reset()`` or after the first step, or when the episode
            draws no detections (``state`` mode without ``draw_detections``).
        """
        state = self._episode.state
        if state is None or state.steps:
            raise RuntimeError("episode_record() replays the episode from its start: call it "
                               "right after reset()")
        if not self.params.draw_detections:
            raise RuntimeError("this episode draws no detections (obs_mode='state'): make the "
                               "env with draw_detections=True for its record and bound")
        replay = copy.deepcopy(self)
        backend = replay._backend(replay.rng)
        t = self.params.horizon
        blocks = [state.block]
        block = replay.physics.block
        for start in range(block, t, block):
            _, block = transition.simulate_block(self.params, state.plan, blocks[-1], start,
                                                 replay.physics.data, backend)
            blocks.append(block)
        replay.close()

        def joined(name):
            parts = [getattr(b, name) for b in blocks]
            return None if parts[0] is None else np.concatenate(parts)[:t]

        heard = joined("heard") if self.calibration.config.propagation_delay else None
        return EpisodeRecord(
            positions=joined("positions"), dt=self._dt, sound_speed=state.plan.sound_speed,
            current_speed=np.linalg.norm(joined("current"), axis=1), heard=heard,
            fading=joined("fades"), working=joined("nodes"),
        )

    def trajectory_bound(self, prior: MotionPrior | None = None) -> float:
        """The posterior Cramér–Rao bound (m) on this episode's ``rmse`` episode metric:
        ``sqrt(mean_k trace(P_k))`` over the scored steps, ``P_k`` the PCRB of the
        position given the measurements up to step k, from this environment's own
        measurement model along this episode's true trajectory
        (:mod:`auv_envs.tasks.acoustic.bound`; ``prior`` its motion model). Call it right
        after ``reset()`` (:meth:`episode_record`)."""
        return bound_rmse(self.calibration.array, self.episode_record(), prior)

    def summarise(self, truth: dict) -> dict:
        return transition.summary(self.params, self._episode.state)
