"""Acoustic tracking of an underwater manipulator's end effector [GMPHD].

``auv_envs/AcousticTracking-v0``: an acoustic source on the end effector of a
6-DOF arm, carried through a 300 m x 300 m tank by a neutrally buoyant
carrier and disturbed by the current, is heard by eight hydrophone nodes. The
agent estimates the end effector's position from the multi-band detection
sets (:mod:`auv_envs.core.acoustics`).

The agent's estimates do not act on the physics, so the environment simulates
the physics and draws the measurements in blocks of ``BLOCK`` sample periods,
vectorised over the block, and serves them one period per step. The result is
the same as stepping one period at a time (the blocks are a computational
device, not a change of model) and many times faster.
"""

from __future__ import annotations

import copy
import dataclasses
import math

import mujoco
import numpy as np
from dm_control import mjcf
from gymnasium import spaces

from auv_envs import metrics
from auv_envs.core import difficulty as levels
from auv_envs.core.acoustics import (
    GMPHD_FLOW_NOISE_LEVEL,
    AcousticConfig,
    HydrophoneArray,
    Measurements,
)
from auv_envs.core.assets import asset_path
from auv_envs.core.env import (
    ActionValidator,
    TaskEnv,
    check_choice,
    check_image_size,
    check_positive_int,
)
from auv_envs.tasks.acoustic.bound import EpisodeRecord, MotionPrior, bound_rmse

OBS_MODES = ("state", "measurements")
TRAJECTORIES = ("dynamic", "static")
#: Current speed ranges in m/s ([GMPHD] §3.4's disturbance levels).
DISTURBANCES = {"low": (0.05, 0.15), "medium": (0.16, 0.30), "high": (0.31, 0.50)}
#: [GMPHD] Table 1: the five static end-effector positions (tank frame, m).
STATIC_POINTS = (
    (50.0, 102.0, -10.0),
    (170.0, 234.0, -15.5),
    (215.0, 236.0, -12.0),
    (289.0, 245.0, -8.0),
    (47.0, 251.0, -20.0),
)
#: TCFE ([GMPHD] §3.4): the entropy of the lengths of the estimate's consecutive
#: differences in bins of this width (m). ``tcfe`` is the paper's literal definition (first
#: differences), which also bins the end effector's own speed; ``tcfe_fluctuation`` uses
#: second differences, which the true motion leaves at 0 (measured: ``CHANGELOG.md``).
TCFE_BIN_WIDTH = 0.01
#: Sample periods simulated and measured per block (0.5 s at 100 Hz).
BLOCK = 50
#: Source positions kept from before a block for the propagation delay (0.64 s at 100 Hz:
#: sound crosses the tank's 424 m diagonal in 0.28 s).
HISTORY = 64
#: The arm's nominal joint posture (rad): the source about 3.5 m ahead of
#: and 0.9 m below the carrier's centre.
NOMINAL_POSTURE = (0.0, 0.6, -1.2, 0.0, 0.6, 0.0)
#: Carrier route limits (m): keeps the end effector inside the work area
#: x, y in [40, 295], z in [-25, -5].
ROUTE_XY = (45.0, 285.0)
ROUTE_Z = (-20.0, -8.0)
CARRIER_SPEED = (0.2, 0.8)
ARM_JOINTS = ("shoulder_yaw", "shoulder_pitch", "elbow", "wrist_roll", "wrist_pitch",
              "tool_roll")
CARRIER_JOINTS = ("carrier_x", "carrier_y", "carrier_z", "carrier_yaw")
#: Seconds of the end effector's path that ``render()`` draws, and of estimates in its close-up.
RENDER_TRAIL = 10.0
RENDER_CLOSEUP = 2.0


#: The ``paper`` level's measurement model: [GMPHD]'s tank (§4.1: 300 m x 300 m, water at
#: 20 +- 2 degC, three current generators, precisely surveyed node positions). Each parameter
#: beyond the defaults is physical (:mod:`auv_envs.core.acoustics` documents the models):
#:
#: * ``flow_noise_level``: the current generators' radiated noise (``GMPHD_FLOW_NOISE_LEVEL``).
#: * ``propagation_delay``: sound takes R / c to reach a node, so a moving source is heard
#:   where it was (not a parameter: the physics of a finite sound speed).
#: * ``sound_speed_error_std`` 1 m/s: the tank's mean temperature known to about 0.3 degC
#:   (dc/dT = 3.2 m/s per degC at 20 degC, Mackenzie 1981); our assumption.
#: * ``fluctuation_intensity`` 3.5e-4, the rms fractional sound-speed fluctuation (about
#:   0.1 degC of thermal microstructure and the generators' turbulence; correlation length
#:   10 m and time 2 s, our assumptions): calibrated against [GMPHD]'s dynamic RMSE (0.18 m
#:   average, Table 2).
#: * ``source_level`` 110 dB re 1 uPa at 1 m (10 dB below the ``easy`` source): calibrated
#:   against [GMPHD]'s static positioning error (0.11 m average over Table 1's five points);
#:   it also makes each band's own noise, which fusing the bands averages, matter beside the
#:   errors the bands share.
PAPER_ACOUSTICS = AcousticConfig(
    flow_noise_level=GMPHD_FLOW_NOISE_LEVEL,
    propagation_delay=True,
    sound_speed_error_std=1.0,
    fluctuation_intensity=3.5e-4,
    fluctuation_length=10.0,
    fluctuation_time=2.0,
    source_level=110.0,
)
#: The ``hard`` level: beyond [GMPHD]'s tank. A quieter source (105 dB) so that the far
#: nodes and the high bands fade, twice the microstructure (7e-4), a temperature known to
#: 1 degC (3 m/s), band fading of the saturated (Rayleigh) regime (5.6 dB rms, Flatte et al.
#: 1979), boundaries that reflect more (surface 2 dB, bottom 6 dB loss: stronger ghosts),
#: three false alarms per band and period, and node dropouts (Gilbert-Elliott outages, our
#: choice: each node drops out once a minute on average, ``node_dropout_rate`` 1/60 per s,
#: for 5 s on average, so it is out 7.7 % of the time and all eight work 53 % of it).
HARD_ACOUSTICS = dataclasses.replace(
    PAPER_ACOUSTICS,
    source_level=105.0,
    fluctuation_intensity=7e-4,
    sound_speed_error_std=3.0,
    fading_std=5.6,
    surface_loss=2.0,
    bottom_loss=6.0,
    clutter_rate=3.0,
    node_dropout_rate=1.0 / 60.0,
    node_dropout_duration=5.0,
)


def build_tank_model() -> mujoco.MjModel:
    """Compose the tank and the carrier + arm from ``assets/acoustic`` with mjcf."""
    tank = mjcf.from_path(str(asset_path("acoustic/tank.xml")))
    rig = mjcf.from_path(str(asset_path("acoustic/carrier_arm.xml")))
    rig.model = "rig"
    tank.worldbody.attach(rig)
    return mujoco.MjModel.from_xml_string(tank.to_xml_string(), assets=tank.get_assets())


@dataclasses.dataclass(frozen=True)
class AcousticCalibration:
    """What a tracker may know about the sensing system (read-only).

    Attributes:
      array: the :class:`~auv_envs.core.acoustics.HydrophoneArray`, with the
        node positions, the noise model (``array.model(p)``) and the exact
        measurement function (``array.noise_free(p)``).
      hydrophone_positions: (8, 3) node positions in the tank frame (m);
        index 0 is node 1, the TDOA reference.
      sound_speed: m/s. sample_rate: fs in Hz. band_centres: (Q,) Hz.
      bandwidth: Hz per band. config: the full
        :class:`~auv_envs.core.acoustics.AcousticConfig`.
      tank_size: (x, y) extent in m; tank_depth: m (surface z = 0).
      work_area: ((x, y, z) low, (x, y, z) high) where the end effector moves.
      max_detections: K, the padded detection-set size per band.
    """

    array: HydrophoneArray
    hydrophone_positions: np.ndarray
    sound_speed: float
    sample_rate: float
    band_centres: np.ndarray
    bandwidth: float
    config: AcousticConfig
    tank_size: tuple[float, float]
    tank_depth: float
    work_area: tuple[tuple[float, float, float], tuple[float, float, float]]
    max_detections: int


@dataclasses.dataclass
class _Episode:
    """Everything an episode changes besides MuJoCo's state (deep-copied to pickle)."""

    steps: int = 0
    horizon: int = 0
    done: bool = False
    carrier_ref: np.ndarray | None = None  # (T+1, 4) x, y, z, yaw
    carrier_vel: np.ndarray | None = None  # (T+1, 4)
    arm_ref: np.ndarray | None = None  # (T+1, 6)
    current: np.ndarray | None = None  # (T+1, 3)
    clock_offsets: np.ndarray | None = None
    sound_speed: float | None = None  # the water's true sound speed, m/s
    history: np.ndarray | None = None  # (<= HISTORY, 3) source positions before the block
    wander: np.ndarray | None = None  # (N,) the nodes' unit travel-time wander, last period
    fading: np.ndarray | None = None  # (Q, N) the bands' fades at the last period, dB
    fades: np.ndarray | None = None  # (B, Q, N) the bands' fades over the block, dB
    heard: np.ndarray | None = None  # (B, 3) or (B, N, 3) the positions measured in the block
    nodes: np.ndarray | None = None  # (B, N) which nodes work, per period of the block
    block_start: int = 0
    positions: np.ndarray | None = None  # (B, 3) of the current block
    velocities: np.ndarray | None = None
    measurements: Measurements | None = None
    estimates: np.ndarray | None = None  # (T, 3)
    truths: np.ndarray | None = None  # (T, 3)
    squared_error_sum: float = 0.0
    static_point: int | None = None


def plan_route(rng: np.random.Generator, n: int, dt: float):
    """A carrier route of ``n`` samples: straight segments, curves and pauses.

    Segment kinds come from shuffled bags of two straights, two curves and
    one pause, so every route mixes all three: straight (4-12 s), curve
    (6-15 s, turning 30-120 deg), pause (1.5-5 s); speeds
    uniform in ``CARRIER_SPEED`` and a slow climb or descent (|w| <= 0.05 m/s)
    while moving. Near the route limits a segment heads back towards the
    centre. Returns (reference (n, 4) of x, y, z, yaw and its rate (n, 4)).
    """
    lo, hi = ROUTE_XY
    centre = 0.5 * (lo + hi)
    speed = np.zeros(n)
    turn = np.zeros(n)
    climb = np.zeros(n)
    heading0 = np.zeros(n)
    position = np.array([rng.uniform(lo + 20, hi - 20), rng.uniform(lo + 20, hi - 20),
                         rng.uniform(*ROUTE_Z)])
    start = position.copy()
    heading = rng.uniform(-math.pi, math.pi)
    i = 0
    bag: list[int] = []
    while i < n:
        if not bag:
            bag = list(rng.permutation((0, 0, 1, 1, 2)))
        kind = bag.pop()
        duration = (rng.uniform(4, 12), rng.uniform(6, 15), rng.uniform(1.5, 5))[kind]
        count = min(n - i, max(1, int(round(duration / dt))))
        v = rng.uniform(*CARRIER_SPEED) if kind != 2 else 0.0
        w = 0.0
        home = math.atan2(centre - position[1], centre - position[0])
        near_edge = np.any(position[:2] < lo + 25) or np.any(position[:2] > hi - 25)
        if near_edge and math.cos(heading - home) < 0.5:
            heading = home + rng.uniform(-0.5, 0.5)
        if kind == 1:
            sign = rng.choice((-1.0, 1.0))
            w = sign * rng.uniform(math.pi / 6, 2 * math.pi / 3) / (count * dt)
        vz = rng.uniform(-0.05, 0.05) if v > 0 else 0.0
        if not ROUTE_Z[0] + 1 < position[2] < ROUTE_Z[1] - 1:
            vz = math.copysign(abs(vz), 0.5 * sum(ROUTE_Z) - position[2])
        speed[i : i + count], turn[i : i + count], climb[i : i + count] = v, w, vz
        heading0[i : i + count] = heading + w * dt * np.arange(count)
        heading += w * dt * count
        travel = heading0[i : i + count]
        position = position + dt * np.array(
            [np.sum(v * np.cos(travel)), np.sum(v * np.sin(travel)), vz * count]
        )
        i += count
    velocity = np.stack([speed * np.cos(heading0), speed * np.sin(heading0), climb, turn], 1)
    reference = np.empty((n, 4))
    reference[0, :3] = start
    reference[1:, :3] = start + np.cumsum(velocity[:-1, :3] * dt, axis=0)
    reference[:, 3] = heading0
    reference[:, 0:2] = np.clip(reference[:, 0:2], lo, hi)
    reference[:, 2] = np.clip(reference[:, 2], *ROUTE_Z)
    return reference, velocity


def current_profile(rng: np.random.Generator, n: int, dt: float, speed_range) -> np.ndarray:
    """A horizontal current (n, 3): speed sweeping ``speed_range``, direction veering.

    ``speed(t) = lo + (hi - lo) (1 + sin(2 pi t / T_s + phi)) / 2`` with
    ``T_s`` uniform in 20-60 s, and direction ``theta0 + 0.3 sin(2 pi t / T_d
    + psi)`` with ``T_d`` uniform in 30-90 s.
    """
    lo, hi = speed_range
    t = dt * np.arange(n)
    speed = lo + (hi - lo) * 0.5 * (1 + np.sin(2 * np.pi * t / rng.uniform(20, 60)
                                               + rng.uniform(0, 2 * np.pi)))
    direction = rng.uniform(-np.pi, np.pi) + 0.3 * np.sin(
        2 * np.pi * t / rng.uniform(30, 90) + rng.uniform(0, 2 * np.pi)
    )
    return np.stack([speed * np.cos(direction), speed * np.sin(direction), np.zeros(n)], 1)


class AcousticPhysics:
    """The MuJoCo model/data pair with the ids this task needs, resolved once."""

    def __init__(self, model: mujoco.MjModel):
        self.model = model
        self.data = mujoco.MjData(model)
        self.source = model.site("rig/source").id
        self.hydrophones = np.array(
            [model.site_pos[model.site(f"hydrophone_{i}").id] for i in range(1, 9)]
        )
        self.carrier_qpos = np.array([model.joint(f"rig/{j}").qposadr[0] for j in CARRIER_JOINTS])
        self.arm_qpos = np.array([model.joint(f"rig/{j}").qposadr[0] for j in ARM_JOINTS])
        self.carrier_pos_act = np.array(
            [model.actuator(f"rig/{j}_pos").id for j in CARRIER_JOINTS]
        )
        self.carrier_vel_act = np.array(
            [model.actuator(f"rig/{j}_vel").id for j in CARRIER_JOINTS]
        )
        self.arm_act = np.array([model.actuator(f"rig/{j}").id for j in ARM_JOINTS])
        # The tank as assets/acoustic/tank.xml draws it: the bottom plane spans it.
        bottom = model.geom("bottom")
        self.tank_depth = -float(bottom.pos[2])
        self.tank_size = (2.0 * float(bottom.size[0]), 2.0 * float(bottom.size[1]))
        self._jac = np.zeros((3, model.nv))

    def source_state(self) -> tuple[np.ndarray, np.ndarray]:
        """Source position and velocity at the current state (kinematics must be current)."""
        model, data = self.model, self.data
        mujoco.mj_comPos(model, data)
        mujoco.mj_jacSite(model, data, self._jac, None, self.source)
        return data.site_xpos[self.source].copy(), self._jac @ data.qvel

    def source_offset(self, posture) -> np.ndarray:
        """Source position relative to the carrier at yaw 0 in a given arm posture."""
        data = mujoco.MjData(self.model)
        data.qpos[self.arm_qpos] = posture
        mujoco.mj_kinematics(self.model, data)
        return data.site_xpos[self.source].copy()


class AcousticTrackingEnv(TaskEnv):
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

    **Action space.** ``Box([0, 0, -30], [300, 300, 0], (3,), float32)``: the
    agent's estimate of the end effector's position (tank frame, m) at the
    time of the latest observation. Finite values outside the tank are
    clipped; NaN, inf and non-numbers raise ``ValueError``.

    **Observation space** (``obs_mode``; padded to K = ``max_detections`` per band):

    ================  =======================================================
    mode              space
    ================  =======================================================
    ``state``         ``Box((9,), float32)``, privileged: end-effector
                      position (3) and velocity (3), current velocity (3)
    ``measurements``  ``Dict`` of float64 arrays: ``tdoa`` (Q, K, 7) s,
                      ``azimuth`` (Q, K, 8) rad in [-pi, pi], ``elevation``
                      (Q, K, 8) rad in [0, pi] (from the upward vertical),
                      ``mask`` ``MultiBinary((Q, K))`` (1: a real detection);
                      with node dropouts also ``node_mask``
                      ``MultiBinary((8,))`` (1: the node works)
    ================  =======================================================

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
    m) and follows a seeded route (:func:`plan_route`); the arm's joints sweep
    sinusoidally about ``NOMINAL_POSTURE`` (amplitudes 0.1-0.35 rad for the
    first three joints, 0.05-0.2 rad for the wrist, periods 12-40 s).
    ``trajectory="static"``: the carrier holds the end effector at one of
    [GMPHD] Table 1's five points (``static_point``; drawn when None) in the
    nominal posture. The current (:func:`current_profile`) sweeps the
    ``disturbance`` level's speed range with a veering direction.

    **Episode end.** No terminal state; truncated after ``time_limit`` s
    (``time_limit * 100`` steps).

    **Info.** Every step: ``estimate_error`` (m; NaN at reset),
    ``running_rmse`` (m; NaN at reset), ``tracked`` (error within
    ``track_gate``), ``is_success`` (running RMSE within ``success_radius``),
    the reward term, ground truth for metrics (``true_position``,
    ``true_velocity``, ``current``, ``detection_origin`` (Q, K): -1 padding,
    0 source, 1 surface ghost, 2 bottom ghost, 3 false alarm), ``time``;
    with node dropouts ``nodes_working``. At reset, with a sound-speed error,
    the episode's true ``sound_speed``. At the end ``episode_metrics``:
    ``rmse``, ``max_error``, ``error_bias`` (norm of the mean error),
    ``tfc``, ``tcfe`` ([GMPHD]'s entropy of the estimate's first differences
    in 1 cm bins, which also scores the source's own speed),
    ``tcfe_fluctuation`` (the same on second differences, 0 for the true
    motion), ``mean_ospa``, ``success``.

    **Arguments.**

    ====================  ===================================================
    argument              meaning (default)
    ====================  ===================================================
    ``obs_mode``          ``"state"``, ``"measurements"`` (``"measurements"``)
    ``disturbance``       current speeds: ``"low"``, ``"medium"``, ``"high"``
                          ([GMPHD] §3.4; ``"medium"``)
    ``trajectory``        ``"dynamic"`` or ``"static"`` (``"dynamic"``)
    ``static_point``      1-5 or None (drawn)
    ``time_limit``        s (60)
    ``acoustic``          :class:`~auv_envs.core.acoustics.AcousticConfig`
                          (the documented model)
    ``error_clip``        m (5)
    ``track_gate``        m (1)
    ``success_radius``    m (0.5)
    ``physics_substeps``  physics steps per 0.01 s period (1)
    ``render_mode``       ``"rgb_array"`` or None
    ``render_size``       (W, H) of ``render()``, at least 8x8 (640x480)
    ``difficulty``        ``"easy"`` (the release), ``"paper"``
                          (:data:`PAPER_ACOUSTICS`, calibrated to [GMPHD]'s
                          tank), ``"hard"`` (:data:`HARD_ACOUSTICS`); sets
                          ``acoustic`` when it is not given
                          (``docs/difficulty.md``)
    ====================  ===================================================

    **Bound.** ``trajectory_bound()``, right after ``reset()``: the posterior
    Cramér–Rao bound (m) on the episode's ``rmse`` from this environment's
    own motion and measurement models along its true trajectory
    (:mod:`auv_envs.tasks.acoustic.bound`; the leaderboard's ``pcrb`` row).

    **Rendering.** ``render_mode="rgb_array"``: a top view, a side view and a
    close-up of the tank with the nodes, the end effector's recent path, the
    latest estimate and the current detections' rays coloured by origin
    (:class:`auv_envs.tasks.acoustic.render.TankPlot`), drawn from the
    episode's record, so rendering changes no observation, reward or draw.

    **Version history.** v0: initial release. Changes within v0 (added
    metrics, opt-in arguments and levels, each leaving the default episodes
    unchanged bit for bit) with their measurements: ``CHANGELOG.md``.
    """

    metadata = {"render_modes": ["rgb_array"], "render_fps": 100}
    _closeables = ("_plot",)

    #: The contract the registry-driven tests read (see tests/conftest.py).
    obs_modes = OBS_MODES
    #: ``difficulty`` levels (:mod:`auv_envs.core.difficulty`): the acoustic measurement model.
    difficulty_presets = {
        "easy": {},
        "paper": {"acoustic": PAPER_ACOUSTICS},
        "hard": {"acoustic": HARD_ACOUSTICS},
    }
    reward_terms = ("estimate",)
    metric_keys = ("estimate_error", "running_rmse", "tracked", "is_success")

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
        physics_substeps: int = 1,
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
            physics_substeps=physics_substeps, render_mode=render_mode,
            render_size=render_size, difficulty=difficulty,
        )
        acoustic = self._apply_difficulty(difficulty, acoustic=acoustic)["acoustic"]
        self._render_size = check_image_size(render_size, "render_size")
        self._init_kwargs["render_size"] = self._render_size
        check_positive_int("physics_substeps", physics_substeps)
        check_choice("disturbance", disturbance, tuple(DISTURBANCES))
        check_choice("trajectory", trajectory, TRAJECTORIES)
        if static_point is not None:
            check_choice("static_point", static_point, range(1, len(STATIC_POINTS) + 1))
        for name in ("time_limit", "error_clip", "track_gate", "success_radius"):
            value = self._init_kwargs[name]
            if not (isinstance(value, int | float) and math.isfinite(value) and value > 0):
                raise ValueError(f"{name} must be a positive number, got {value!r}")
        config = acoustic if acoustic is not None else AcousticConfig()
        if not isinstance(config, AcousticConfig):
            raise TypeError(f"acoustic must be an AcousticConfig, got {type(config).__name__}")

        self.obs_mode = obs_mode
        self.render_mode = render_mode
        self.disturbance = disturbance
        self.trajectory = trajectory
        self._static_point = static_point
        self.physics = AcousticPhysics(build_tank_model())
        self._dt = 1.0 / config.sample_rate
        self.physics.model.opt.timestep = self._dt / physics_substeps
        self._physics_substeps = physics_substeps
        self._horizon = int(round(time_limit * config.sample_rate))
        #: Step period, s (one env step).
        self.dt = self._dt
        #: Steps of an episode (it always runs to its ``time_limit``).
        self.max_episode_steps = self._horizon
        self._error_clip = float(error_clip)
        self._track_gate = float(track_gate)
        self._success_radius = float(success_radius)
        depth = self.physics.tank_depth
        array = HydrophoneArray(self.physics.hydrophones, 0.0, -depth, config)
        band_centres = array.band_centres
        tank_size = self.physics.tank_size
        low = np.array([0.0, 0.0, -depth])
        high = np.array([*tank_size, 0.0])
        self.calibration = AcousticCalibration(
            array=array,
            hydrophone_positions=array.positions,
            sound_speed=config.sound_speed,
            sample_rate=config.sample_rate,
            band_centres=band_centres,
            bandwidth=config.bandwidth,
            config=config,
            tank_size=tank_size,
            tank_depth=depth,
            work_area=((40.0, 40.0, -25.0), (295.0, 295.0, -5.0)),
            max_detections=config.max_detections,
        )
        self._source_offset = self.physics.source_offset(NOMINAL_POSTURE)
        self.action_space = spaces.Box(low.astype(np.float32), high.astype(np.float32),
                                       dtype=np.float32)
        self._validate_action = ActionValidator(self.action_space)
        self.observation_space = self._make_observation_space(array)
        self._episode = _Episode()
        self._plot = None  # the TankPlot, built on the first render()

    def _make_observation_space(self, array: HydrophoneArray) -> spaces.Space:
        if self.obs_mode == "state":
            return spaces.Box(-np.inf, np.inf, shape=(9,), dtype=np.float32)
        q, k, n = array.config.n_bands, array.config.max_detections, array.n_nodes
        bound = np.broadcast_to(array.max_tdoa * 1.1 + 0.01, (q, k, n - 1))
        entries = {
            "tdoa": spaces.Box(-bound, bound, dtype=np.float64),
            "azimuth": spaces.Box(-np.pi, np.pi, shape=(q, k, n), dtype=np.float64),
            "elevation": spaces.Box(0.0, np.pi, shape=(q, k, n), dtype=np.float64),
            "mask": spaces.MultiBinary((q, k)),
        }
        if array.config.node_dropout_rate > 0:
            entries["node_mask"] = spaces.MultiBinary(n)
        return spaces.Dict(entries)

    # ------------------------------------------------------------------ episode hooks
    def _begin_episode(self, rng: np.random.Generator, options: dict | None):
        n = self._horizon + 1
        ep = _Episode(horizon=self._horizon)
        if self.trajectory == "dynamic":
            ep.carrier_ref, ep.carrier_vel = plan_route(rng, n, self._dt)
            t = self._dt * np.arange(n)[:, None]
            amplitude = np.concatenate([rng.uniform(0.1, 0.35, 3), rng.uniform(0.05, 0.2, 3)])
            period = rng.uniform(12.0, 40.0, 6)
            phase = rng.uniform(0, 2 * np.pi, 6)
            ep.arm_ref = NOMINAL_POSTURE + amplitude * (
                np.sin(2 * np.pi * t / period + phase) - np.sin(phase)
            )
        else:
            point = self._static_point or int(rng.integers(1, len(STATIC_POINTS) + 1))
            ep.static_point = point
            ref = np.append(np.asarray(STATIC_POINTS[point - 1]) - self._source_offset, 0.0)
            ep.carrier_ref = np.broadcast_to(ref, (n, 4)).copy()
            ep.carrier_vel = np.zeros((n, 4))
            ep.arm_ref = np.broadcast_to(NOMINAL_POSTURE, (n, 6)).copy()
        ep.current = current_profile(rng, n, self._dt, DISTURBANCES[self.disturbance])
        ep.clock_offsets = self.calibration.array.draw_clock_offsets(rng)
        ep.sound_speed = self.calibration.array.draw_sound_speed(rng)
        ep.estimates = np.full((self._horizon, 3), np.nan)
        ep.truths = np.full((self._horizon, 3), np.nan)

        physics = self.physics
        model, data = physics.model, physics.data
        mujoco.mj_resetData(model, data)
        data.qpos[physics.carrier_qpos] = ep.carrier_ref[0]
        data.qpos[physics.arm_qpos] = ep.arm_ref[0]
        mujoco.mj_forward(model, data)
        self._episode = ep
        self._simulate_block(0)
        extras = {}
        if self.calibration.config.sound_speed_error_std > 0:
            extras["sound_speed"] = ep.sound_speed
        return {"k": 0, "error": float("nan")}, extras

    def _simulate(self, action: np.ndarray) -> dict:
        """Score the estimate ``action`` against the truth at the last observation, then
        move on one sample period (the physics runs a block of periods at a time)."""
        ep = self._episode
        k = ep.steps  # the estimate is scored against the truth at observation k
        truth = ep.positions[k - ep.block_start]
        error = float(np.linalg.norm(action - truth))
        ep.estimates[k] = action
        ep.truths[k] = truth
        ep.squared_error_sum += error * error
        ep.steps = k + 1
        if ep.steps - ep.block_start >= BLOCK:
            self._simulate_block(ep.steps)
        return {"k": ep.steps, "error": error}

    def _assess(self, truth: dict, action: np.ndarray) -> tuple[dict, bool]:
        """The (clipped, normalised) estimate error; an episode ends only at its time limit."""
        return {"estimate": -min(truth["error"], self._error_clip) / self._error_clip}, False

    def _truth(self) -> dict:
        if self._episode.steps < 1:
            raise RuntimeError("no step taken yet: nothing to summarise")
        return {"k": self._episode.steps, "error": float("nan")}

    @property
    def plot(self):
        """The :class:`~auv_envs.tasks.acoustic.render.TankPlot` that draws ``render()``'s
        frames: built on the first render, None before it and after ``close()``."""
        return self._plot

    def _render_frame(self) -> np.ndarray:
        """The tank as an (H, W, 3) uint8 frame (``render_mode="rgb_array"``).

        Drawn from the episode's own record (true positions, estimates and the
        current detections), so rendering changes no observation, reward, info
        or random draw. Before the first reset it draws the empty tank.
        """
        if self._plot is None:
            from auv_envs.tasks.acoustic.render import TankPlot  # matplotlib only when drawing

            self._plot = TankPlot(self.calibration, self._render_size,
                                  track_gate=self._track_gate, trail_seconds=RENDER_TRAIL,
                                  closeup_seconds=RENDER_CLOSEUP)
        ep = self._episode
        if ep.positions is None:  # no episode yet
            return self._plot.frame()
        k = ep.steps
        j = k - ep.block_start
        trail_steps = int(round(RENDER_TRAIL / self._dt))
        first = max(0, k - trail_steps)
        trail = np.concatenate([ep.truths[first:k], ep.positions[j : j + 1]])
        m = ep.measurements
        mask = m.mask[j].ravel()
        n = self.calibration.array.n_nodes
        azimuth = m.azimuth[j].reshape(-1, n)[mask]
        elevation = m.elevation[j].reshape(-1, n)[mask]
        if ep.nodes is not None:  # an out node draws no ray (its zeros are no measurement)
            azimuth[:, ~ep.nodes[j]] = np.nan
            elevation[:, ~ep.nodes[j]] = np.nan
        estimate, error, rmse = None, float("nan"), float("nan")
        if k:
            estimate = ep.estimates[k - 1]
            error = float(np.linalg.norm(estimate - ep.truths[k - 1]))
            rmse = math.sqrt(ep.squared_error_sum / k)
        closeup_steps = int(round(RENDER_CLOSEUP / self._dt))
        return self._plot.frame(
            time=k * self._dt,
            trail=trail,
            estimate=estimate,
            estimate_trail=ep.estimates[max(0, k - closeup_steps) : k],
            azimuth=azimuth,
            elevation=elevation,
            origin=m.origin[j].ravel()[mask],
            error=error,
            rmse=rmse,
        )

    # ------------------------------------------------------------------ internals
    def _simulate_block(self, start: int) -> None:
        """Advance the physics over sample periods [start, start + BLOCK) and measure them."""
        ep = self._episode
        physics = self.physics
        model, data = physics.model, physics.data
        count = min(BLOCK, ep.horizon + 1 - start)
        positions = np.empty((count, 3))
        velocities = np.empty((count, 3))
        wind = model.opt.wind
        ctrl = data.ctrl
        for j in range(count):
            k = start + j
            if k > 0:
                ctrl[physics.carrier_pos_act] = ep.carrier_ref[k]
                ctrl[physics.carrier_vel_act] = ep.carrier_vel[k]
                ctrl[physics.arm_act] = ep.arm_ref[k]
                wind[:] = ep.current[k - 1]
                mujoco.mj_step(model, data, self._physics_substeps)
                mujoco.mj_kinematics(model, data)
            positions[j], velocities[j] = physics.source_state()
        array = self.calibration.array
        heard = positions
        if array.config.propagation_delay:
            track = positions if ep.history is None else np.concatenate([ep.history, positions])
            heard = array.emission_positions(track, count, self._dt, ep.sound_speed)
            ep.history = track[-HISTORY:]
        wander = array.draw_wander(self.np_random, count, ep.wander)
        if wander is not None:
            ep.wander = wander[-1]
        fading = array.draw_fading(self.np_random, count, ep.fading)
        if fading is not None:
            ep.fading = fading[-1]
        nodes = array.draw_node_states(self.np_random, count,
                                       None if ep.nodes is None else ep.nodes[-1])
        ep.nodes = nodes
        ep.fades = fading
        ep.heard = heard
        ep.block_start = start
        ep.positions = positions
        ep.velocities = velocities
        ep.measurements = array.measure(
            self.np_random, heard, ep.clock_offsets,
            np.linalg.norm(ep.current[start:start + count], axis=1), ep.sound_speed, wander,
            fading, nodes,
        )

    def _observation(self, truth: dict):
        ep = self._episode
        k = truth["k"]
        j = k - ep.block_start
        if self.obs_mode == "state":
            return np.concatenate([ep.positions[j], ep.velocities[j], ep.current[k]]).astype(
                np.float32
            )
        m = ep.measurements
        obs = {
            "tdoa": m.tdoa[j].copy(),
            "azimuth": m.azimuth[j].copy(),
            "elevation": m.elevation[j].copy(),
            "mask": m.mask[j].astype(np.int8),
        }
        if ep.nodes is not None:
            obs["node_mask"] = ep.nodes[j].astype(np.int8)
        return obs

    def _info(self, truth: dict) -> dict:
        ep = self._episode
        k, error = truth["k"], truth["error"]
        j = k - ep.block_start
        rmse = math.sqrt(ep.squared_error_sum / k) if k else float("nan")
        info = {
            "estimate_error": error,
            "running_rmse": rmse,
            "tracked": error <= self._track_gate,
            "is_success": rmse <= self._success_radius,
            "true_position": ep.positions[j].copy(),
            "true_velocity": ep.velocities[j].copy(),
            "current": ep.current[k].copy(),
            "detection_origin": ep.measurements.origin[j].copy(),
            "time": k * self._dt,
        }
        if ep.nodes is not None:
            info["nodes_working"] = int(np.count_nonzero(ep.nodes[j]))
        return info

    def episode_record(self) -> EpisodeRecord:
        """The whole episode's truth and realised nuisance, for the bound
        (:class:`~auv_envs.tasks.acoustic.bound.EpisodeRecord`): the true positions at
        the steps the episode scores, the current, the true sound speed, the emission
        positions heard (with propagation delay), the band fades and the node states.

        Plays the episode out on a copy (its generator included), so this episode's
        observations and draws are unchanged. Call it right after ``reset()``.

        Raises:
          RuntimeError: before ``reset()`` or after the first step.
        """
        ep = self._episode
        if ep.positions is None or ep.steps:
            raise RuntimeError("episode_record() replays the episode from its start: call it "
                               "right after reset()")
        replay = copy.deepcopy(self)
        blocks = []
        for start in range(0, ep.horizon, BLOCK):
            if start:
                replay._simulate_block(start)
            blocks.append(replay._episode)
            replay._episode = copy.copy(replay._episode)  # keep this block's arrays
        replay.close()
        t = ep.horizon

        def joined(name):
            parts = [getattr(b, name) for b in blocks]
            return None if parts[0] is None else np.concatenate(parts)[:t]

        heard = joined("heard") if self.calibration.config.propagation_delay else None
        return EpisodeRecord(
            positions=joined("positions"), dt=self._dt, sound_speed=ep.sound_speed,
            current_speed=np.linalg.norm(ep.current[:t], axis=1), heard=heard,
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

    def _episode_metrics(self, truth: dict) -> dict:
        ep = self._episode
        est, truth = ep.estimates[: ep.steps], ep.truths[: ep.steps]
        errors = metrics.position_errors(est, truth)
        rmse = metrics.rmse(est, truth)
        # One estimate per step: the track is "on" the source while within the
        # gate (label 0) and lost otherwise; TFC counts the re-acquisitions.
        labels = np.where(errors <= self._track_gate, 0, metrics.NO_TRACK)
        out = {
            "rmse": rmse,
            "max_error": metrics.max_error(est, truth),
            # The systematic part of the error: rmse^2 = error_bias^2 + (random part)^2.
            "error_bias": float(np.linalg.norm(np.mean(est - truth, axis=0))),
            "tfc": metrics.track_fragmentation_count(labels),
            # [GMPHD] §3.4's TCFE as written (first differences), and the same
            # entropy on second differences, which the true motion leaves at 0.
            "tcfe": metrics.tcfe(est, bin_width=TCFE_BIN_WIDTH),
            "tcfe_fluctuation": metrics.tcfe(est, bin_width=TCFE_BIN_WIDTH, order=2),
            # OSPA between singleton sets {estimate} and {truth} (p = 1, c =
            # error_clip) is min(error, c) per step.
            "mean_ospa": float(np.mean(np.minimum(errors, self._error_clip))),
            "steps": ep.steps,
            "success": bool(rmse <= self._success_radius),
        }
        if ep.static_point is not None:
            out["static_point"] = ep.static_point
        return out
