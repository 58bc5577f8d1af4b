"""The explorer's two ipywidgets panels (``notebooks/10_explore.ipynb``).

* :func:`query_panel`: model, object and query controls; below them the one-line verdict
  (an HTML widget, class ``explore-summary``) and the figure of
  :func:`helpers.study.explorer.query.query_figure` (an Image widget, class ``explore-figure``).
* :func:`byo_panel`: upload a mesh and a crop, press the button, get the rotation
  (:func:`byo_answer`, the same call as ``python -m helpers.study.cli.byo``) and its overlay.

CSS classes name the parts a browser test reads (``tests/test_browser.py``): it compares
what the page shows, not the kernel's state. ipywidgets is imported inside the panel
functions so that importing this module never needs a widget front end.
"""

from __future__ import annotations

import html
import tempfile
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from ..byo import ByoResult, estimate_rotation, overlay_figure
from .query import Explorer, figure_png, inspect_query


def query_panel(make_explorer: Callable[[str], Explorer], models: list[str], objects: list[str],
                first: Explorer, obj: str, index: int, top_k: int = 5) -> Any:
    """A VBox: model dropdown, object dropdown, query slider, verdict line, figure.

    ``make_explorer(name)`` builds the explorer of another model (bank re-encoded, cached);
    ``first`` is the explorer of ``models[0]``'s choice, already built.
    """
    import ipywidgets as w

    state = {"ex": first}
    model_dd = w.Dropdown(options=models, value=first.label if first.label in models else models[0],
                          description="model")
    obj_dd = w.Dropdown(options=objects, value=obj, description="object")
    n = len(first.data.test_q[obj])
    slider = w.IntSlider(value=index, min=0, max=n - 1, description="query", continuous_update=False)
    summary = w.HTML()
    image = w.Image(format="png")
    for widget, cls in ((model_dd, "explore-model"), (obj_dd, "explore-object"), (slider, "explore-query"),
                        (summary, "explore-summary"), (image, "explore-figure")):
        widget.add_class(cls)

    def show(*_: Any) -> None:
        try:
            v = inspect_query(state["ex"], obj_dd.value, slider.value, top_k)
            image.value = figure_png(state["ex"], v)
            summary.value = f"<b>{html.escape(v.summary())}</b>"
        except Exception as e:  # shown in the panel: a widget callback's exception is otherwise invisible
            summary.value = f"<span style='color:#b00'>{html.escape(type(e).__name__ + ': ' + str(e))}</span>"

    def on_model(change: dict) -> None:
        summary.value = f"encoding references with {html.escape(change['new'])}..."
        try:
            state["ex"] = make_explorer(change["new"])
        except Exception as e:  # shown, and the dropdown goes back to the model still in use
            model_dd.unobserve(on_model, names="value")
            model_dd.value = change["old"]
            model_dd.observe(on_model, names="value")
            summary.value = (f"<span style='color:#b00'>model {html.escape(change['new'])}: "
                             f"{html.escape(type(e).__name__ + ': ' + str(e))}</span>")
            return
        show()

    def on_object(change: dict) -> None:
        slider.max = len(state["ex"].data.test_q[change["new"]]) - 1
        slider.value = min(slider.value, slider.max)
        show()

    model_dd.observe(on_model, names="value")
    obj_dd.observe(on_object, names="value")
    slider.observe(show, names="value")
    show()
    return w.VBox([w.HBox([model_dd, obj_dd, slider]), summary, image])


def byo_answer(model: Any, mesh: str | Path, crop: str | Path, n_refs: int, out_png: str | Path,
               render_size: int = 96, device: str = "auto", cache: str | None = None) -> tuple[ByoResult, dict]:
    """Bring-your-own answer: rotation of the object in ``crop`` from ``mesh``, its overlay written
    to ``out_png``; returns (result, JSON-ready summary with the matrix, quaternion and score)."""
    from scipy.spatial.transform import Rotation

    res = estimate_rotation(model, mesh, crop, n_refs=n_refs, render_size=render_size, device=device, cache=cache)
    overlay_figure(res, out_png)
    x, y, z, wq = Rotation.from_matrix(res.R_m2c).as_quat()
    return res, {"R_m2c": np.round(res.R_m2c, 4).tolist(), "quaternion_wxyz": [round(float(c), 4) for c in (wq, x, y, z)],
                 "score": round(res.score, 4), "alternatives_deg_from_best":
                 [round(a["deg_from_best"], 1) for a in res.alternatives]}


def byo_panel(model: Any, n_refs: int, render_size: int = 96, device: str = "auto", cache: str | None = None) -> Any:
    """A VBox: mesh and crop uploads, reference count, button; the answer and its overlay below."""
    import ipywidgets as w

    mesh_up = w.FileUpload(accept=".obj,.ply,.stl,.glb,.gltf,.off", description="mesh")
    crop_up = w.FileUpload(accept="image/*", description="crop")
    refs = w.BoundedIntText(value=n_refs, min=1, max=100000, description="references")
    button = w.Button(description="Estimate rotation", button_style="primary")
    answer = w.HTML()
    image = w.Image(format="png")
    for widget, cls in ((mesh_up, "byo-mesh"), (crop_up, "byo-crop"), (button, "byo-run"), (answer, "byo-answer"),
                        (image, "byo-overlay")):
        widget.add_class(cls)

    def run(_: Any) -> None:
        if not mesh_up.value or not crop_up.value:
            answer.value = "<span style='color:#b00'>upload a mesh file and a crop image first</span>"
            return
        # The uploads live as files for one answer only (the renders are cached by the mesh's sha256).
        with tempfile.TemporaryDirectory(prefix="byo-upload-") as d:
            tmp = Path(d)
            try:
                paths = []
                for up in (mesh_up, crop_up):
                    f = up.value[-1]
                    p = tmp / Path(f["name"]).name  # the upload's own name: its suffix tells trimesh/OpenCV the format
                    p.write_bytes(bytes(f["content"]))
                    paths.append(p)
                answer.value = f"rendering {refs.value} references of {html.escape(paths[0].name)}..."
                _, out = byo_answer(model, paths[0], paths[1], refs.value, tmp / "overlay.png", render_size, device,
                                    cache)
                image.value = (tmp / "overlay.png").read_bytes()
                answer.value = f"<pre>{html.escape(str(out))}</pre>"
            except Exception as e:  # bad files: the same clear messages as the Python call, shown in the panel
                answer.value = f"<span style='color:#b00'>{html.escape(type(e).__name__ + ': ' + str(e))}</span>"

    button.on_click(run)
    return w.VBox([w.HBox([mesh_up, crop_up, refs, button]), answer, image])
