"""The interactive 3D view in the site page: three.js (r147, from the npm registry, MIT licence),
its GLTFLoader and OrbitControls, vendored in ``vendor/three/`` and copied into each site folder with
``vendor/viewer.js``, so that the page works offline from a file system or a USB stick.

The page loads the model from ``model.glb.js``, the site's ``model.glb`` as a base64 string in a
classic script: browsers refuse ``fetch`` and module scripts on ``file://`` pages, but run classic
scripts. It is progressive enhancement: the viewer shows itself only when JavaScript and WebGL work;
otherwise the static renders are the view.
"""

from __future__ import annotations

import base64
import shutil
from pathlib import Path

VENDOR = Path(__file__).resolve().parent / "vendor"
SCRIPTS = ("three/three.min.js", "three/GLTFLoader.js", "three/OrbitControls.js", "viewer.js")
"""Vendored files, in the order the page loads them (``viewer.js`` last, after ``model.glb.js``)."""
FOLDER = "viewer"


def write_viewer(site_dir: Path, glb: Path) -> dict[str, str]:
    """Copy the viewer's scripts (and three.js's licence) into ``site_dir/viewer/`` and write
    ``model.glb.js``; returns their artifacts."""
    folder = site_dir / FOLDER
    folder.mkdir(exist_ok=True)
    files = {}
    for name in SCRIPTS + ("three/LICENSE",):
        target = folder / Path(name).name
        shutil.copyfile(VENDOR / name, target)
        files[f"viewer-{target.stem.lower()}"] = target.relative_to(site_dir).as_posix()
    encoded = base64.b64encode(glb.read_bytes()).decode("ascii")
    (site_dir / "model.glb.js").write_text(f'window.cisternModelGlb = "{encoded}";\n', encoding="ascii")
    files["viewer-model"] = "model.glb.js"
    return files


def script_sources() -> list[str]:
    """The ``src`` of every script the page loads, in order."""
    names = [f"{FOLDER}/{Path(name).name}" for name in SCRIPTS]
    return names[:-1] + ["model.glb.js", names[-1]]
