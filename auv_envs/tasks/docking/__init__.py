"""The docking-station approach: the six-light station [OFNMPC] and the L-shaped
lamp array [LAMP].

``env`` the Gymnasium environments, ``transition`` the episode written once for
them and the batched env, ``rules`` the geometry and rules, ``station`` the scene,
``optics`` the water's light, ``navigation`` the DVL, AHRS, depth sensor and USBL,
``plant`` the CPU plants, ``mjx_plant`` the batched one (JAX), ``mission`` the whole
approach, ``randomization`` the batched worlds' domain randomiser.
"""
