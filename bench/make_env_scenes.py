#!/usr/bin/python3
"""Writes the environment-lit scenes of `peers.py --env`: a Lambertian sphere on a Lambertian floor lit only
by an environment map, under two maps:

  bench/scenes/env-sky.json  the bundled sky (scenes/sky.hdr), turned 60 degrees;
  bench/scenes/env-sun.json  bench/scenes/sun-256x128.hdr, written here: a dim blue sky (radiance 0.2, 0.3,
                             0.5) and a small sun of 13 texels (a disc of radius 2 texels) of radiance 900,
                             33 degrees above the horizon, between -z and +x: 5.9 W/m^2 at normal incidence
                             from 1/1900 of the sphere, against the sky's 0.9 on the floor, which only
                             importance sampling of the map finds.

Standard library only (the Radiance writer of make_material_scene.py). Deterministic: running it again
writes the same bytes."""
import json
import sys
from pathlib import Path

sys.dont_write_bytecode = True
HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
import make_material_scene as mk  # noqa: E402

SCENES = HERE / "scenes"
SUN_MAP = SCENES / "sun-256x128.hdr"
SKY, SUN_SKY, SUN = (0.2, 0.3, 0.5), 900.0, (32, 40)  # the dim sky; the sun's radiance and centre texel (x, y)


def sun_map(path, width=256, height=128):
    cx, cy = SUN
    rows = [[(SUN_SKY,) * 3 if (x - cx) ** 2 + (y - cy) ** 2 <= 4 else SKY for x in range(width)]
            for y in range(height)]
    mk.write_hdr(path, width, height, rows)


def scene(env_file, rotation):
    """The sphere and floor under ENV_FILE (relative to bench/scenes), as validate_materials.py's diffuse-sky."""
    return {"camera": {"position": [0, 1.2, -4], "look_at": [0, 0.6, 0], "up": [0, 1, 0], "fov": 40},
            "film": {"width": 64, "height": 64},
            "render": {"spp": 256, "max_depth": 8},
            "environment": {"file": env_file, "strength": 1, "rotation": rotation},
            "materials": {"floor": {"type": "diffuse", "albedo": [0.6, 0.6, 0.6]},
                          "ball": {"type": "diffuse", "albedo": [0.8, 0.35, 0.2]}},
            "shapes": [{"type": "quad", "material": "floor",
                        "vertices": [[-3, 0, -3], [3, 0, -3], [3, 0, 3], [-3, 0, 3]]},
                       {"type": "sphere", "material": "ball", "center": [0, 0.7, 0], "radius": 0.7,
                        "subdivisions": 5}]}


def write():
    """Writes the map and both scenes; returns the scene paths."""
    SCENES.mkdir(parents=True, exist_ok=True)
    sun_map(SUN_MAP)
    paths = {"env-sky": SCENES / "env-sky.json", "env-sun": SCENES / "env-sun.json"}
    paths["env-sky"].write_text(json.dumps(scene("../../scenes/sky.hdr", 60), indent=1) + "\n")
    paths["env-sun"].write_text(json.dumps(scene(SUN_MAP.name, 0), indent=1) + "\n")
    return paths


if __name__ == "__main__":
    for path in [*write().values(), SUN_MAP]:
        print(f"wrote {path}")
