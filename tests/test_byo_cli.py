"""``python -m helpers.study.cli.byo MESH CROP``: a rotation, its quaternion, the score and the next best."""

import json

import cv2
import numpy as np
import pytest

from helpers.core.configs import RenderConfig
from helpers.core.rotations import geodesic_deg
from helpers.study import byo
from helpers.study.cli import byo as byo_cli

pytestmark = pytest.mark.gl


def test_cli_finds_the_rotation_of_a_rendered_view_and_names_bad_paths(tmp_path, manifest, capsys):
    entry = manifest.object(manifest.held_out_objects()[0])
    mesh = entry.mesh.resolve()
    obj = byo.custom_object(mesh)
    # The crop is one of the references the command will render (same mesh, colour, count, seed).
    refs, R = byo.render_custom_references(obj, 64, RenderConfig(size=64, render_size=160), cache=tmp_path / "c")
    crop = tmp_path / "crop.png"
    cv2.imwrite(str(crop), cv2.cvtColor(np.ascontiguousarray(refs[10]), cv2.COLOR_RGB2BGR))
    out_png = tmp_path / "overlay.png"
    args = [str(mesh), str(crop), "--model", "split1", "--refs", "64", "--device", "cpu",
            "--cache", str(tmp_path / "c"), "--out", str(out_png)]
    assert byo_cli.main(args + ["--json"]) == 0
    res = json.loads(capsys.readouterr().out)
    assert geodesic_deg(np.array(res["R_m2c"]), R[10].astype(np.float64)) < 30.0
    w, x, y, z = res["quaternion_wxyz"]
    assert abs(w * w + x * x + y * y + z * z - 1) < 1e-6
    assert len(res["alternatives"]) == 4 and all(a["score"] <= res["score"] for a in res["alternatives"])
    assert out_png.stat().st_size > 0
    # the benchmark's symmetry rule on the user's mesh (racecar: the manifest declares a half-turn for it), and
    # the answers as right as R_m2c under what it found
    sym = res["symmetries"]
    assert len(sym["discrete"]) >= 1 and len(res["equivalent_R_m2c"]) == len(sym["discrete"])
    for d, E in zip(sym["discrete"], res["equivalent_R_m2c"]):
        assert 45.0 <= d["angle_deg"] <= 315.0
        assert abs(geodesic_deg(np.array(E), np.array(res["R_m2c"])) - min(d["angle_deg"], 360 - d["angle_deg"])) < 1e-3
    assert byo_cli.main(args) == 0  # text form, second call from the cache
    text = capsys.readouterr().out
    assert "quaternion (w, x, y, z)" in text and "next best" in text and "equally right" in text
    assert byo_cli.main([str(tmp_path / "nope.obj"), str(crop), "--model", "split1", "--device", "cpu"]) == 2
    assert "nope.obj does not exist" in capsys.readouterr().err
    assert byo_cli.main([str(mesh), str(tmp_path / "nope.png"), "--model", "split1", "--device", "cpu"]) == 2
    assert "nope.png does not exist" in capsys.readouterr().err
