"""Docking control: [OFNMPC]'s offset-free NMPC and the scripted PD reference controller."""
