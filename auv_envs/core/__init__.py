"""Shared simulation parts: frames, vehicles, hydrodynamics, camera, rendering."""
