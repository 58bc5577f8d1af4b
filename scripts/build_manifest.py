"""Regenerate data_manifest.yaml from the catalogue below and the installed packages.

Run after changing the catalogue or upgrading a pinned source package:

    python scripts/build_manifest.py

It records each file's package, version, path, sha256, licence and role. The
study itself never runs this; it only verifies against the committed result.
"""

from __future__ import annotations

import importlib.metadata as md
import sys
from pathlib import Path

import yaml

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "src"))
from helpers.core.fileio import sha256_file  # noqa: E402
from helpers.data.manifest import module_dir  # noqa: E402

SOURCES = {
    "pybullet": ("pybullet", "pybullet_data", "zlib"),
    "robosuite": ("robosuite", "robosuite", "MIT"),
    "pyvista": ("pyvista", "pyvista", "MIT"),
    "gymnasium_robotics": ("gymnasium-robotics", "gymnasium_robotics", "MIT"),
    "metaworld": ("metaworld", "metaworld", "MIT"),
    "skimage": ("scikit-image", "skimage", "BSD-3-Clause (images: see skimage/data/README.txt)"),
    "sklearn": ("scikit-learn", "sklearn", "BSD-3-Clause (images: see sklearn/datasets/images/README.txt)"),
}

RS = "models/assets/objects/meshes/"
GR = "envs/assets/"
# name, role, split, source, mesh path, extra files, colour (None = textured), description
OBJECTS = [
    # split 1 (LineMOD #1 stand-ins)
    ("duck", "train", 1, "pybullet", "duck.obj", ["duck.mtl", "duckCM.png"], None, "textured rubber duck"),
    ("bunny", "train", 1, "pybullet", "bunny.obj", [], (0.78, 0.62, 0.45), "Stanford bunny"),
    ("mug", "train", 1, "pybullet", "objects/mug.obj", [], (0.25, 0.45, 0.8), "mug with handle"),
    ("airplane", "train", 1, "pyvista", "examples/airplane.ply", [], (0.75, 0.75, 0.78), "airliner"),
    # split 2
    ("teddy", "train", 2, "pybullet", "teddy2_VHACD_CHs.obj", [], (0.6, 0.4, 0.2), "teddy bear (convex pieces)"),
    ("ant", "train", 2, "pyvista", "examples/ant.ply", [], (0.55, 0.2, 0.15), "ant"),
    ("bread", "train", 2, "robosuite", RS + "bread.obj", [RS + "bread.mtl", "models/assets/textures/bread.png"], None, "loaf of bread, textured"),
    ("cereal", "train", 2, "robosuite", RS + "cereal.obj", [RS + "cereal.mtl", "models/assets/textures/cereal.png"], None, "cereal box, printed texture"),
    # split 3
    ("milk", "train", 3, "robosuite", RS + "milk.obj", [RS + "milk.mtl", "models/assets/textures/ceramic.png"], None, "milk carton"),
    ("husky", "train", 3, "pybullet", "husky/meshes/base_link.stl", [], (0.85, 0.7, 0.1), "Husky rover chassis"),
    ("panda_hand", "train", 3, "pybullet", "franka_panda/meshes/visual/hand.obj",
     ["franka_panda/meshes/visual/hand.mtl"], (0.9, 0.9, 0.9), "Franka gripper hand"),
    ("kettle", "train", 3, "gymnasium_robotics", GR + "kitchen_franka/kitchen_assets/meshes/kettle.stl", [], (0.7, 0.15, 0.15), "kettle"),
    ("palm", "train", 3, "gymnasium_robotics", GR + "adroit_hand/resources/meshes/palm.stl", [], (0.8, 0.65, 0.55), "robot hand palm"),
    # held-out: never trained on in any split
    ("racecar", "held-out", None, "pybullet", "racecar/meshes/chassis.STL", [], (0.2, 0.2, 0.25), "toy racecar chassis"),
    ("kuka_link", "held-out", None, "pybullet", "kuka_iiwa/meshes/link_2.obj", ["kuka_iiwa/meshes/link_2.mtl"], (0.95, 0.5, 0.1), "robot arm link"),
    ("panda_link", "held-out", None, "pybullet", "franka_panda/meshes/visual/link2.obj",
     ["franka_panda/meshes/visual/link2.mtl"], (0.9, 0.9, 0.9), "Franka arm link"),
    ("hammerhead", "held-out", None, "metaworld", "assets/objects/meshes/hammer/hammerhead.stl", [], (0.5, 0.5, 0.55), "hammer head"),
    ("rock_a", "held-out", None, "pybullet", "random_urdfs/000/000.obj", [], (0.45, 0.6, 0.35), "procedural random object 000"),
    ("rock_b", "held-out", None, "pybullet", "random_urdfs/001/001.obj", [], (0.6, 0.35, 0.6), "procedural random object 001"),
    ("microwave", "held-out", None, "gymnasium_robotics", GR + "kitchen_franka/kitchen_assets/meshes/micro.stl", [], (0.85, 0.85, 0.8), "microwave oven body"),
]

BACKGROUNDS = [
    ("astronaut", "train", "skimage", "data/astronaut.png"),
    ("chelsea", "train", "skimage", "data/chelsea.png"),
    ("motorcycle", "train", "skimage", "data/motorcycle_left.png"),
    ("brick", "train", "skimage", "data/brick.png"),
    ("grass", "train", "skimage", "data/grass.png"),
    ("china", "train", "sklearn", "datasets/images/china.jpg"),
    ("coffee", "test", "skimage", "data/coffee.png"),
    ("rocket", "test", "skimage", "data/rocket.jpg"),
    ("gravel", "test", "skimage", "data/gravel.png"),
    ("flower", "test", "sklearn", "datasets/images/flower.jpg"),
]


def _entry(module: str, path: str) -> dict:
    p = module_dir(module) / path
    if not p.is_file():
        raise SystemExit(f"missing {p}")
    return {"path": path, "sha256": sha256_file(p)}


def main() -> None:
    sources = {k: {"package": pkg, "version": md.version(pkg), "module": mod, "licence": lic}
               for k, (pkg, mod, lic) in SOURCES.items()}
    objects = []
    for name, role, split, src, mesh, extras, color, desc in OBJECTS:
        mod = sources[src]["module"]
        o = {"name": name, "role": role, "split": split, "source": src, "description": desc,
             "licence": sources[src]["licence"], "mesh": _entry(mod, mesh),
             "extra_files": [_entry(mod, e) for e in extras]}
        if color is not None:
            o["color"] = list(color)
        objects.append(o)
    backgrounds = [{"name": n, "role": "background", "split": s, "source": src, "licence": sources[src]["licence"],
                    "file": _entry(sources[src]["module"], p)} for n, s, src, p in BACKGROUNDS]
    doc = {"version": 1, "sources": sources, "objects": objects, "backgrounds": backgrounds}
    out = Path(__file__).resolve().parents[1] / "data_manifest.yaml"
    header = ("# Every mesh, texture and background photo used by the study.\n"
              "# Generated by scripts/build_manifest.py; helpers.data.manifest verifies every sha256.\n"
              "# role: train = LineMOD-like benchmark object (unseen in its own split, seen in the others),\n"
              "#       held-out = never trained on, background = photo behind real-like queries.\n")
    out.write_text(header + yaml.safe_dump(doc, sort_keys=False, width=120))
    print(f"wrote {out}: {len(objects)} objects, {len(backgrounds)} backgrounds")


if __name__ == "__main__":
    main()
