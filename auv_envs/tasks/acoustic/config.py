"""The acoustic family's configuration and parameters, built without an environment.

As the docking family's (:mod:`auv_envs.tasks.docking.config`): :func:`default_config`
gives ``auv_envs/AcousticTracking-v2``'s configuration (or a superseded version's; a
frozen :class:`AcousticTrackingConfig`, changed with ``replace``), and :func:`params`
builds from it everything the configuration fixes (a frozen :class:`AcousticSetup`: the
tank's model, what an agent may know, the transition's parameters and the spaces),
checking every value. The task on the CPU
(:class:`auv_envs.tasks.acoustic.env.AcousticTrackingTask`, which the one Gymnasium env
runs) and the task on JAX (:class:`auv_envs.tasks.acoustic.jax_task.AcousticJax`) are
both built from a setup.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
from gymnasium import spaces

from auv_envs.core import difficulty as levels
from auv_envs.core.acoustics import (
    GMPHD_FLOW_NOISE_LEVEL,
    NOISE_DRAWS,
    AcousticConfig,
    HydrophoneArray,
)
from auv_envs.core.env import check_choice, check_positive_int
from auv_envs.core.task import Config, Setup
from auv_envs.tasks.acoustic import transition
from auv_envs.tasks.acoustic.plant import INTEGRATORS, AcousticPhysics, compose_tank_model
from auv_envs.tasks.acoustic.transition import DISTURBANCES, NOMINAL_POSTURE, STATIC_POINTS

OBS_MODES = ("state", "measurements")
TRAJECTORIES = ("dynamic", "static")
#: The carrier route's planners (``planner=``): from v2 on ``"segments"``
#: (:func:`~auv_envs.tasks.acoustic.transition.draw_route`, the same code on NumPy and
#: JAX), in v0/v1 ``"tabulated"`` (:func:`~auv_envs.tasks.acoustic.transition.plan_route`).
PLANNERS = ("segments", "tabulated")


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



#: ``difficulty`` levels (:mod:`auv_envs.core.difficulty`): the measurement model.
PRESETS = {"easy": {}, "paper": {"acoustic": PAPER_ACOUSTICS},
           "hard": {"acoustic": HARD_ACOUSTICS}}


@dataclasses.dataclass(frozen=True)
class AcousticTrackingConfig(Config):
    """Everything that fixes the acoustic tracking task: the arguments of
    ``gym.make("auv_envs/AcousticTracking-v2")`` (the environment's docstring gives each
    one's meaning, type and default) without the rendering ones; changed by ``replace``
    (``TypeError`` for an unknown field). ``draw_detections``: the detections are drawn
    in every mode (the ``measurements`` mode and a rendering environment draw them
    anyway)."""

    obs_mode: str = "measurements"
    disturbance: str = "medium"
    trajectory: str = "dynamic"
    static_point: int | None = None
    time_limit: float = 60.0
    acoustic: AcousticConfig | None = None
    error_clip: float = 5.0
    track_gate: float = 1.0
    success_radius: float = 0.5
    physics_substeps: int = 2
    integrator: str = "euler"
    noise_draws: str = "kept"
    draw_detections: bool = False
    planner: str = "segments"
    difficulty: str = levels.DEFAULT_LEVEL


def default_config(env_id: str = "auv_envs/AcousticTracking-v2") -> AcousticTrackingConfig:
    """The configuration ``gym.make(env_id)`` builds (a superseded id's: its keywords
    applied; :data:`auv_envs.families.FAMILIES`).

    Raises:
        ValueError: ``env_id`` is not an acoustic tracking id.
    """
    from auv_envs.families import family

    entry = family(env_id)
    if entry.env_id != "auv_envs/AcousticTracking-v2":
        raise ValueError(f"{env_id!r} is not an acoustic tracking id")
    return AcousticTrackingConfig().replace(**entry.previous.get(env_id, {}))


def config_of(env_id: str, **arguments) -> AcousticTrackingConfig:
    """The configuration of ``gym.make(env_id, **arguments)`` (without the rendering
    arguments).

    Raises:
        TypeError: an argument the id does not take.
    """
    return default_config(env_id).replace(**arguments)


@dataclasses.dataclass(frozen=True)
class AcousticSetup(Setup):
    """What an :class:`AcousticTrackingConfig` fixes (:func:`params`), for the Gymnasium
    environment and the task on JAX alike.

    Attributes:
        config: the configuration it was built from.
        acoustic: the measurement model (the configuration's ``acoustic``, or its
            ``difficulty`` level's).
        model_source: the composed MJCF (:class:`~auv_envs.core.assets.MJCF`).
        model: its compiled MuJoCo model, the integrator and timestep set: a Gymnasium
            environment built from this setup simulates this very model.
        calibration: what an agent may know (:class:`AcousticCalibration`).
        params: the transition's parameters
            (:class:`~auv_envs.tasks.acoustic.transition.AcousticParams`).
        observation_space, action_space: the spaces.
        dt: the sample period, s.
        max_episode_steps: steps of an episode (it always runs to ``time_limit``).
    """

    acoustic: AcousticConfig


def params(config: AcousticTrackingConfig) -> AcousticSetup:
    """Everything ``config`` fixes, each value checked (module docstring).

    Raises:
        TypeError: a value of the wrong type (``acoustic``, ``draw_detections``).
        ValueError: a value out of its range or not one of its choices.
    """
    if not isinstance(config, AcousticTrackingConfig):
        raise TypeError(f"params takes an AcousticTrackingConfig, got {type(config).__name__}")
    check_choice("obs_mode", config.obs_mode, OBS_MODES)
    acoustic = levels.resolve(PRESETS, config.difficulty,
                              {"acoustic": config.acoustic})["acoustic"]
    check_positive_int("physics_substeps", config.physics_substeps)
    check_choice("integrator", config.integrator, tuple(INTEGRATORS))
    check_choice("noise_draws", config.noise_draws, NOISE_DRAWS)
    check_choice("planner", config.planner, PLANNERS)
    if not isinstance(config.draw_detections, bool):
        raise TypeError(f"draw_detections must be True or False, got "
                        f"{config.draw_detections!r}")
    check_choice("disturbance", config.disturbance, tuple(DISTURBANCES))
    check_choice("trajectory", config.trajectory, TRAJECTORIES)
    if config.static_point is not None:
        check_choice("static_point", config.static_point, range(1, len(STATIC_POINTS) + 1))
    for name in ("time_limit", "error_clip", "track_gate", "success_radius"):
        value = getattr(config, name)
        if not (isinstance(value, int | float) and math.isfinite(value) and value > 0):
            raise ValueError(f"{name} must be a positive number, got {value!r}")
    acoustic = acoustic if acoustic is not None else AcousticConfig()
    if not isinstance(acoustic, AcousticConfig):
        raise TypeError(f"acoustic must be an AcousticConfig, got {type(acoustic).__name__}")

    model_source = compose_tank_model()
    model = model_source.compile()
    dt = 1.0 / acoustic.sample_rate
    model.opt.timestep = dt / config.physics_substeps
    model.opt.integrator = INTEGRATORS[config.integrator]
    physics = AcousticPhysics(model)  # the tank's geometry, by name
    horizon = int(round(config.time_limit * acoustic.sample_rate))
    depth = physics.tank_depth
    array = HydrophoneArray(physics.hydrophones, 0.0, -depth, acoustic)
    tank_size = physics.tank_size
    low = np.array([0.0, 0.0, -depth])
    high = np.array([*tank_size, 0.0])
    calibration = AcousticCalibration(
        array=array,
        hydrophone_positions=array.positions,
        sound_speed=acoustic.sound_speed,
        sample_rate=acoustic.sample_rate,
        band_centres=array.band_centres,
        bandwidth=acoustic.bandwidth,
        config=acoustic,
        tank_size=tank_size,
        tank_depth=depth,
        work_area=((40.0, 40.0, -25.0), (295.0, 295.0, -5.0)),
        max_detections=acoustic.max_detections,
    )
    task_params = transition.AcousticParams(
        obs_mode=config.obs_mode, trajectory=config.trajectory,
        static_point=config.static_point, current_range=DISTURBANCES[config.disturbance],
        dt=dt, horizon=horizon, array=array,
        source_offset=physics.source_offset(NOMINAL_POSTURE),
        error_clip=float(config.error_clip), track_gate=float(config.track_gate),
        success_radius=float(config.success_radius),
        planner=config.planner,
        draw_detections=config.draw_detections or config.obs_mode == "measurements")
    action_space = spaces.Box(low.astype(np.float32), high.astype(np.float32),
                              dtype=np.float32)
    return AcousticSetup(
        config=config, acoustic=acoustic, model_source=model_source, model=model,
        calibration=calibration, params=task_params,
        observation_space=_observation_space(config.obs_mode, array),
        action_space=action_space, dt=dt, max_episode_steps=horizon)


def _observation_space(obs_mode: str, array: HydrophoneArray) -> spaces.Space:
    """The observation space of ``obs_mode`` with ``array``'s measurement sets."""
    if obs_mode == "state":
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
