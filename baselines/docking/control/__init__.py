"""Docking control: seed 003's offset-free NMPC and the scripted PD reference controller."""
