"""Scenes and checks shared by the service tests."""

from __future__ import annotations

import time

import numpy as np


def small_scene(name="box", particles_per_side=10, radius=0.02):
    """A block of n × n particles resting in a 1 m tank (100 particles: ~1 ms a frame)."""
    side = particles_per_side * 2 * radius
    return {"name": name, "dimension": 2, "particle_radius": radius,
            "domain": {"min": [0, 0], "max": [1, 1]},
            "fluid_blocks": [{"min": [0, 0], "max": [side, side]}]}


def small_recipe(name, template, frames):
    """small_scene plus a capture of its whole tank for `frames` frames (a recipe, templates/README.md):
    ~1 ms a frame, so 5 frames record at once and 100 000 run until cancelled."""
    recipe = small_scene(name)
    recipe["capture"] = {"name": template, "region": {"min": [0, 0], "max": [1, 1]}, "frames": frames}
    return recipe


def heavy_frames_scene(name="heavy"):
    """20 000 particles settling under weak gravity, one cheap WCSPH substep a frame (~4 ms a
    frame on one thread): 120 kB a frame, ~30 MB of frames per second."""
    return {"name": name, "dimension": 2, "particle_radius": 0.005, "gravity": [0, -1],
            "domain": {"min": [0, 0], "max": [2, 1.2]},
            "fluid_blocks": [{"min": [0, 0], "max": [2, 1]}],
            "solver": {"method": "wcsph", "stiffness": 1000},
            "settings": {"frame_rate": 1000, "dt_max": 0.001}}


def blowup_scene(name="blowup"):
    """A runaway simulation as the watchdog sees one: 1 s frames at substeps of at most 1 ms
    against a limit of 20 substeps per frame, so frame 1 is stopped (the session's error state)."""
    scene = small_scene(name)
    scene["settings"] = {"frame_rate": 1, "dt_max": 0.001, "max_substeps_per_frame": 20}
    return scene


def drop_scene_without_instances(client, name="drop2d-copy"):
    """scenes/drop2d.json as the server has it, its template instances taken out (inline)."""
    scene = client.scene("drop2d")
    scene = {k: v for k, v in scene.items() if k != "instances"}
    scene["name"] = name
    return scene


def positions_of(frame_json):
    """A REST JSON frame's positions as (count, dimension)."""
    return np.asarray(frame_json["positions"], np.float64).reshape(frame_json["count"], frame_json["dimension"])


def quantum(frame_json):
    """The largest quantization error of a frame recorded against its domain (per axis)."""
    dim = frame_json["dimension"]
    extent = np.asarray(frame_json["domain_max"][:dim]) - np.asarray(frame_json["domain_min"][:dim])
    return extent / 65535.0


def wait_until(predicate, timeout=120.0, interval=0.02, what="condition"):
    """Polls until predicate() holds; the timeout only catches a hang (a sanitized build on a busy
    machine is many times slower than a release build on a quiet one)."""
    deadline = time.monotonic() + timeout
    while True:
        value = predicate()
        if value:
            return value
        if time.monotonic() > deadline:
            raise TimeoutError(f"{what} not reached within {timeout} s")
        time.sleep(interval)
