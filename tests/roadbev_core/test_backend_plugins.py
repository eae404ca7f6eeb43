"""Backends found by name: the built-in ones, a plugin package installed from outside the tree
(its ``roadbev.backends`` entry points), a ``module:attr`` path, and the refusals of each."""

from __future__ import annotations

import ast
import re
import subprocess
import sys
import textwrap
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest

from roadbev_core import backend_plugins
from roadbev_core.backend_plugins import BUILTIN_BACKENDS, available, find, is_backend_name, option_backend
from roadbev_core.backends import BackendError, RefinedBackend, create, takes_checkpoint
from roadbev_core.config import GridSpec, ParamError, RoadbevConfig, StereoCamera
from roadbev_core.frame import Frame
from roadbev_core.geometry import Attitude
from roadbev_core.pipeline import Pipeline, check_config

REPO = Path(__file__).resolve().parents[2]
BUILTIN = ["adabins", "bev_sweep", "bm", "ensemble", "gwcnet", "mono", "sgbm", "stereo"]
# A backend package as a user would write it: no roadbev code but the protocol's types.
TOY_MODULE = '''
import numpy as np

from roadbev_core.frame import Estimate


class Toy:
    """A flat road ``height`` above the reference plane."""

    needs_stereo = False

    def __init__(self, grid, height=0.0):
        self.name = "toy"
        self.grid = grid
        self.height = float(height)

    def estimate(self, frame):
        shape = self.grid.shape
        return Estimate(np.full(shape, self.height, np.float32), np.full(shape, 0.01, np.float32))


def create(grid, **options):
    return Toy(grid, **options)


def not_a_backend(grid, **options):
    return object()


NOT_CALLABLE = 3
'''
TOY_ENTRY_POINTS = {
    "toy": "toy_backend:create",
    "not_a_backend": "toy_backend:not_a_backend",
    "not_callable": "toy_backend:NOT_CALLABLE",
    "missing": "toy_backend:nothing",
    "fails_to_import": "toy_broken:create",
}
TOY_MODULES = ("toy_backend", "toy_broken", "other_backend")


def install(site: Path, dist: str, entry_points: dict[str, str], modules: dict[str, str]) -> None:
    """Install a distribution into ``site`` as pip would (modules, a .dist-info with entry points)."""
    for name, text in modules.items():
        (site / f"{name}.py").write_text(textwrap.dedent(text))
    info = site / f"{dist}-0.1.dist-info"
    info.mkdir()
    (info / "METADATA").write_text(f"Metadata-Version: 2.1\nName: {dist}\nVersion: 0.1\n")
    lines = [f"{name} = {target}" for name, target in entry_points.items()]
    (info / "entry_points.txt").write_text("[roadbev.backends]\n" + "\n".join(lines) + "\n")


@pytest.fixture
def site(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Iterator[Path]:
    """A folder outside the tree, put on sys.path; the toy modules are forgotten afterwards."""
    folder = tmp_path / "site"
    folder.mkdir()
    monkeypatch.syspath_prepend(str(folder))
    yield folder
    for name in TOY_MODULES:
        sys.modules.pop(name, None)


@pytest.fixture
def toy(site: Path) -> Path:
    install(site, "toy_backend", TOY_ENTRY_POINTS,
            {"toy_backend": TOY_MODULE, "toy_broken": "raise ImportError('toy needs a library that is missing')\n"})
    return site


def test_the_built_in_backends_are_known_without_package_metadata() -> None:
    assert [name for name in available() if name in BUILTIN_BACKENDS] == BUILTIN
    assert set(BUILTIN) <= set(available())
    assert find("bm").source == "built in" and find("bm").target == "roadbev_core.backends.image_view:create_bm"
    assert takes_checkpoint("stereo") and takes_checkpoint("mono") and not takes_checkpoint("bm")


def test_setup_py_declares_the_built_in_backends_as_entry_points() -> None:
    tree = ast.parse((REPO / "setup.py").read_text())
    declared = next(
        value for node in ast.walk(tree) if isinstance(node, ast.Dict)
        for key, value in zip(node.keys, node.values, strict=True)
        if isinstance(key, ast.Constant) and key.value == backend_plugins.ENTRY_POINT_GROUP
    )
    lines = ast.literal_eval(declared)
    assert dict(line.replace(" ", "").split("=") for line in lines) == dict(BUILTIN_BACKENDS)


def test_choosing_a_backend_by_name_imports_no_backend() -> None:
    code = ("import sys\n"
            "from roadbev_core.config import RoadbevConfig\n"
            "params = {'backend': 'stereo', 'stereo.runtime': 'torch', 'checkpoint': 'x.pt'}\n"
            "config = RoadbevConfig.from_params(params)\n"
            "assert config.backend.options_of() == {'runtime': 'torch', 'checkpoint': 'x.pt'}\n"
            "loaded = sorted(m for m in sys.modules if m.startswith('roadbev_core.backends') or m == 'torch')\n"
            "assert not loaded, loaded\n")
    subprocess.run([sys.executable, "-c", code], check=True, cwd=REPO)


def test_a_plugin_installed_from_outside_the_tree_is_created_by_name(toy: Path) -> None:
    assert "toy" in available() and is_backend_name("toy")
    plugin = find("toy")
    assert (plugin.target, plugin.source) == ("toy_backend:create", "toy_backend 0.1")
    assert "toy_backend" not in sys.modules  # listed, not imported
    grid = GridSpec()
    backend = create("toy", grid, height=0.02)
    assert isinstance(backend, RefinedBackend) and backend.name == "toy" and vars(backend.inner)["height"] == 0.02
    assert create("toy", grid, raw=True).grid == grid
    assert not takes_checkpoint("toy")


def test_a_plugin_is_configured_and_run_through_the_config_and_the_pipeline(toy: Path) -> None:
    config = check_config(RoadbevConfig.from_params({"backend": "toy", "toy.height": 0.02, "require_imu": False,
                                                     "map.enabled": False}))
    assert config.backend.name == "toy" and config.backend.options_of() == {"height": 0.02}
    assert option_backend("toy.height") == "toy"
    camera = StereoCamera.rsrd_half().scaled(0.25)
    pipeline = Pipeline(config, configure_process=False)
    frame = Frame(np.zeros((camera.height, camera.width, 3), np.uint8), None, camera, Attitude(0.0, 0.0), 1)
    out = pipeline.process_frame(frame)
    seen = np.isfinite(out.estimate.elevation)
    assert seen.any() and np.allclose(out.estimate.elevation[seen], 0.02)


def test_a_module_path_names_a_backend_installed_without_entry_points(site: Path) -> None:
    (site / "other_backend.py").write_text(TOY_MODULE)
    assert "other_backend:create" not in available() and is_backend_name("other_backend:create")
    config = RoadbevConfig.from_params({"backend": "other_backend:create", "other_backend:create.height": 0.03})
    assert config.backend.options_of() == {"height": 0.03}
    backend = create(config.backend.name, config.grid, **config.backend.options_of())
    assert backend.name == "toy" and vars(backend)["inner"].height == 0.03


@pytest.mark.parametrize(
    "name, reason",
    [
        ("not_a_backend", "backend plugin 'not_a_backend' \\(toy_backend:not_a_backend, toy_backend 0.1\\) returned "
                          "'object', not a Backend: it lacks name, grid, needs_stereo, estimate"),
        ("not_callable", "backend plugin 'not_callable' .* is 'int', not a factory"),
        ("missing", "backend plugin 'missing' .*: module toy_backend has no attribute 'nothing'"),
        ("fails_to_import", "backend plugin 'fails_to_import' \\(toy_broken:create, toy_backend 0.1\\) cannot be "
                            "imported: ImportError: toy needs a library that is missing"),
        ("no_such_module_anywhere:create", "backend plugin 'no_such_module_anywhere:create' "
                                           "\\(no_such_module_anywhere:create, module:attr path\\) cannot be imported: "
                                           "ModuleNotFoundError"),
        ("magic", "unknown backend 'magic'; choose from adabins, bev_sweep, bm, ensemble, fails_to_import, gwcnet, "
                  "missing, mono, not_a_backend, not_callable, sgbm, stereo, toy$"),
        ("toy", "backend 'toy': .*unexpected keyword argument 'colour'"),
    ],
)
def test_a_plugin_that_does_not_work_is_refused_by_name(toy: Path, name: str, reason: str) -> None:
    with pytest.raises(BackendError, match=reason):
        create(name, colour="red")


def test_a_known_backend_with_an_option_but_no_value_is_refused_not_imported_as_a_path() -> None:
    # "bm:plane_parallax_px" has the shape of a module:attr path; its module is the backend bm
    assert not is_backend_name("bm:plane_parallax_px") and is_backend_name("bm")
    with pytest.raises(BackendError, match=re.escape("'bm:plane_parallax_px' is backend 'bm' with an option but no "
                                                     "value: give it as bm:OPTION=VALUE")):
        find("bm:plane_parallax_px")
    with pytest.raises(ParamError, match=r"pace_backend must be empty or one of .*; got 'bm:plane_parallax_px'"):
        RoadbevConfig.from_params({"pace_backend": "bm:plane_parallax_px"})
    assert RoadbevConfig.from_params({"pace_backend": "bm:plane_parallax_px=16"}).backend.pace_backend == (
        "bm:plane_parallax_px=16")


def test_an_unknown_name_in_the_config_lists_the_plugins_too(toy: Path) -> None:
    with pytest.raises(ParamError, match=r"backend must be one of adabins, bev_sweep, .*, stereo, toy; got 'magic'"):
        RoadbevConfig.from_params({"backend": "magic"})
    with pytest.raises(ParamError, match=r"unknown parameter 'magic\.height'"):
        RoadbevConfig.from_params({"magic.height": 1.0})


def test_the_packages_own_entry_points_add_nothing_and_a_second_claim_on_a_name_is_refused(site: Path) -> None:
    install(site, "roadbev_ros", dict(BUILTIN_BACKENDS), {})  # this package, installed with its metadata
    assert available() == BUILTIN
    assert find("bm").conflict == ""
    install(site, "other_backend", {"bm": "other_backend:create"}, {"other_backend": TOY_MODULE})
    backend_plugins.forget_entry_points()
    assert available() == BUILTIN
    declared_twice = ("backend 'bm' is declared twice: built in: roadbev_core.backends.image_view:create_bm and "
                      "other_backend 0.1: other_backend:create; uninstall one of them")
    with pytest.raises(BackendError, match=re.escape(declared_twice)):
        create("bm")
