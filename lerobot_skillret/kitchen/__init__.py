"""Panda kitchen benchmark (robosuite 1.5): scene, tasks, scripted primitives, data generators and gym envs.

Import-light: this package's `__init__` imports nothing heavy; robosuite/mujoco load only in scene-level modules.
"""
