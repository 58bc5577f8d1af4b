"""Build ``.gpu/``: what ``scripts/gpu_zoo/run.py`` needs on a lent GPU machine that has PyTorch but none
of this study's rendering packages and no network (the ``device`` tool of this workplace).

    .venv/bin/python scripts/gpu_zoo/bundle.py            # build .gpu/
    .venv/bin/python scripts/gpu_zoo/bundle.py detach     # before the device tool's run (see detach)
    .venv/bin/python scripts/gpu_zoo/bundle.py attach     # right after it

``.gpu/`` (ignored by git through ``.git/info/exclude``) then holds
  mods/<module>/...   the manifest's files of the benchmark objects and background photos, and the extra
                      training objects' meshes (``data_extra_objects.yaml``), laid out as the packages that
                      ship them (each a stub package, found by :func:`helpers.data.manifest.module_dir`; no
                      code of those packages travels)
  whl/                wheels of trimesh, pyrender-maintained, PyOpenGL, freetype-py, pyglet (Python 3.12)
  gl/                 glvnd's EGL/GL loader packages (.deb; NVIDIA's driver supplies the vendor library)
  REVISION            the git commit and dirty flag of this checkout (the copy sent carries a .git of
                      another commit, so $HELPERS_GIT_REVISION tells the trainers this one)
Why not carry rendered views instead: 13 objects x 1,544 views at 96 px are about 0.5 GB; the meshes and
photos are a few MB, and the GPU machine renders them in seconds.
"""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
OUT = REPO / ".gpu"
WHEELS = ["trimesh==5.2.0", "pyrender-maintained==1.0.1", "PyOpenGL==3.1.10", "freetype-py==2.5.1", "pyglet==2.1.19"]
GL_DEBS = ["libegl1", "libglvnd0", "libopengl0", "libgl1", "libglx0", "libgles2"]


def copy_manifest_files() -> int:
    """Copy every file of the ``train``-role objects and the backgrounds; returns bytes copied."""
    sys.path.insert(0, str(REPO / "src"))
    from helpers.data.manifest import load_manifest

    m = load_manifest()
    entries = [f for o in m.objects if o.role == "train" for f in o.files()] + [b.file for b in m.backgrounds]
    total = 0
    for f in entries:
        dst = OUT / "mods" / f.module / f.path
        dst.parent.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(f.resolve(), dst)
        (OUT / "mods" / f.module / "__init__.py").touch()  # a stub package: wins over an installed one
        total += dst.stat().st_size
    return total


def copy_extra_meshes() -> int:
    """Copy the meshes of the extra training objects (``data_extra_objects.yaml``, issue #44 screen e; the
    ``screen-extra*`` recipes render them) and the material file beside each, if any; returns bytes copied.
    All of them (about 17 MB), not only the first N a recipe takes: the bundle does not depend on the recipes."""
    from helpers.data.extra_objects import load_extras

    total = 0
    for o in load_extras().objects.values():
        src = o.mesh.resolve()
        for f in [src] + [p for p in [src.with_suffix(".mtl")] if p.is_file()]:
            dst = OUT / "mods" / o.mesh.module / Path(o.mesh.path).parent / f.name
            dst.parent.mkdir(parents=True, exist_ok=True)
            shutil.copyfile(f, dst)
            total += dst.stat().st_size
    return total


def download() -> None:
    """Wheels for CPython 3.12 manylinux and the GL loader .debs (package registries only)."""
    (OUT / "whl").mkdir(parents=True, exist_ok=True)
    subprocess.run([sys.executable, "-m", "pip", "download", "-q", "--no-deps", "--only-binary=:all:",
                    "--python-version", "3.12", "--implementation", "cp", "--platform", "manylinux_2_28_x86_64",
                    "--platform", "manylinux_2_17_x86_64", "--platform", "manylinux1_x86_64",
                    "-d", str(OUT / "whl"), *WHEELS], check=True)
    gl = OUT / "gl"
    gl.mkdir(parents=True, exist_ok=True)
    if not list(gl.glob("*.deb")):
        lists = Path("/tmp/gpu_zoo_apt")
        (lists / "partial").mkdir(parents=True, exist_ok=True)
        opts = ["-oAPT::Architecture=amd64", "-oAPT::Architectures=amd64", f"-oDir::State::Lists={lists}"]
        subprocess.run(["apt-get", *opts, "update", "-q"], check=True, capture_output=True)
        subprocess.run(["apt-get", *opts, "download", *GL_DEBS], check=True, cwd=gl)


HEAVY = ("models", "reports")  # tracked, together over the tool's 64 MiB; the GPU machine needs neither
EXCLUDE = REPO / ".git" / "info" / "exclude"


def detach() -> None:
    """Untrack (in the index only) and ignore models/ and reports/ so that the tree sent stays under 64 MiB.
    Commit nothing until :func:`attach` has run."""
    backup = EXCLUDE.with_name("exclude.gpu_zoo")
    if backup.exists():
        raise SystemExit(f"bundle: {backup} exists: already detached (run `bundle.py attach`)")
    backup.write_text(EXCLUDE.read_text() if EXCLUDE.exists() else "")
    EXCLUDE.write_text(backup.read_text() + "".join(f"/{d}/\n" for d in HEAVY))
    subprocess.run(["git", "rm", "-r", "-q", "--cached", *HEAVY], cwd=REPO, check=True)


def attach() -> None:
    """Undo :func:`detach`."""
    backup = EXCLUDE.with_name("exclude.gpu_zoo")
    if not backup.exists():
        raise SystemExit("bundle: not detached")
    EXCLUDE.write_text(backup.read_text())
    subprocess.run(["git", "reset", "-q", "--", *HEAVY], cwd=REPO, check=True)
    backup.unlink()


def main() -> int:
    cmd = sys.argv[1] if len(sys.argv) > 1 else "build"
    if cmd in ("detach", "attach"):
        detach() if cmd == "detach" else attach()
        return 0
    if cmd != "build":
        raise SystemExit(f"bundle.py: expected build, detach or attach, got {cmd!r}")
    if (OUT / "mods").exists():
        shutil.rmtree(OUT / "mods")
    n = copy_manifest_files() + copy_extra_meshes()
    download()
    from helpers.study.provenance import git_revision  # src/ is on sys.path (copy_manifest_files)

    (OUT / "REVISION").write_text(json.dumps(git_revision(REPO)))  # build before `detach`: it stages deletions
    size = sum(p.stat().st_size for p in OUT.rglob("*") if p.is_file())
    print(f"bundle: {OUT} ({size / 2**20:.1f} MiB; manifest files {n / 2**20:.1f} MiB)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
