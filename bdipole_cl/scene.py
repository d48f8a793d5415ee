"""Scenes: ``bdipole_cl.scene.load(path) -> Scene``, ``Scene.plan() -> Plan``,
``Plan.run()`` (the implementation is ``bdipole_cl.jobs.scene``; the file format
``bdipole_cl.io.scene_file``)."""
from .jobs.scene import Plan, PlannedJob, Scene, SceneError, bake, load, plan

__all__ = ["Plan", "PlannedJob", "Scene", "SceneError", "bake", "load", "plan"]
