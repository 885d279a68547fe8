"""SMPL, GMM-prior and regressor pickles that try to run code: each is refused before anything runs.

Every gadget would create a marker file if the loader ran it; each test asserts the error names the
object the file asked for and that the marker does not exist afterwards.
"""

from __future__ import annotations

import builtins
import os
import pickle
import subprocess
from pathlib import Path

import numpy as np
import numpy.testing._private.utils as np_test_utils
import pytest
import yaml
from test_body_models import V_SMALL, _made_up_smpl, _smpl_config

from smplify3d_ros.body import load_body_model
from smplify3d_ros.body.smpl_model import SmplBody, SmplFileError, load_arrays


class _Reduce:
    """An object that pickles as `func(*args)`: what a hostile file holds."""

    def __init__(self, func, *args) -> None:
        self.func, self.args = func, args

    def __reduce__(self):
        return self.func, self.args

    def __call__(self, *args):  # the pickler wants a callable as a reduce's first item; never called here
        raise AssertionError("a gadget is only pickled")


def _in_model(gadget, protocol: int = 4) -> bytes:
    """The gadget as one entry of an otherwise ordinary model dict."""
    return pickle.dumps({"v_template": np.zeros((3, 3)), "shapedirs": gadget}, protocol=protocol)


def _code(marker: Path) -> str:
    return f"open({str(marker)!r}, 'w').close()"


def _getattr_chain(marker: Path) -> bytes:
    """getattr(__import__('os'), 'system')('touch marker'): no forbidden name but builtins."""
    system = _Reduce(getattr, _Reduce(__import__, "os"), "system")
    return _in_model(_Reduce(system, f"touch {marker}"))


# gadget name -> (name the error must show, builder of the file's bytes from the marker path)
GADGETS = {
    "exec": ("builtins.exec", lambda m: _in_model(_Reduce(builtins.exec, _code(m)))),
    "exec_py2_spelling": ("__builtin__.exec", lambda m: _in_model(_Reduce(builtins.exec, _code(m)), protocol=0)),
    "eval": ("builtins.eval", lambda m: _in_model(_Reduce(builtins.eval, _code(m)))),
    "numpy_runstring": ("numpy.testing._private.utils.runstring",
                        lambda m: _in_model(_Reduce(np_test_utils.runstring, _code(m), {}))),
    # os.system pickles as posix.system; a file can still spell it os.system (protocol 0, by hand)
    "os_system": ("os.system", lambda m: f"cos\nsystem\n(S{str(f'touch {m}')!r}\ntR.".encode()),
    "posix_system": ("posix.system", lambda m: _in_model(_Reduce(os.system, f"touch {m}"))),
    "subprocess_popen": ("subprocess.Popen", lambda m: _in_model(_Reduce(subprocess.Popen, ["touch", str(m)]))),
    "subprocess_check_call": ("subprocess.check_call",
                              lambda m: _in_model(_Reduce(subprocess.check_call, ["touch", str(m)]))),
    "getattr_chain": ("builtins.getattr", _getattr_chain),
    # __import__ first, its module kept in the memo, then getattr(memo, 'system')(...): by hand
    "import": ("builtins.__import__", lambda m: (
        f"(cbuiltins\n__import__\n(S'os'\ntRp0\ncbuiltins\ngetattr\n(g0\nS'system'\ntR(S{f'touch {m}'!r}\ntRt."
    ).encode()),
}


def _hostile_file(tmp_path: Path, gadget: str, name: str = "model.pkl") -> tuple[Path, Path, str]:
    """(hostile file, marker it would create, object name the refusal must show)."""
    marker = tmp_path / f"marker_{gadget}"
    expected, build = GADGETS[gadget]
    path = tmp_path / name
    path.write_bytes(build(marker))
    return path, marker, expected


def _assert_refused(excinfo, path: Path, expected: str, marker: Path) -> None:
    message = str(excinfo.value)
    assert f"refusing to load {expected} from {path}" in message
    assert "\n" not in message
    assert not marker.exists(), "the gadget ran"


def test_gadgets_would_run_without_the_allowlist(tmp_path):
    """The hostile files are real: a plain unpickler runs a harmless sample of them (exec, eval,
    runstring), which creates the marker."""
    for gadget in ("exec", "eval", "numpy_runstring"):
        path, marker, _ = _hostile_file(tmp_path, gadget)
        pickle.loads(path.read_bytes())
        assert marker.exists(), gadget


@pytest.mark.parametrize("gadget", sorted(GADGETS))
def test_load_arrays_refuses(tmp_path, gadget):
    path, marker, expected = _hostile_file(tmp_path, gadget)
    with pytest.raises(SmplFileError) as excinfo:
        load_arrays(path)
    _assert_refused(excinfo, path, expected, marker)


@pytest.mark.parametrize("role", ["model", "regressor", "gmm"])
@pytest.mark.parametrize("gadget", sorted(GADGETS))
def test_from_config_refuses_each_file_role(tmp_path, rng, gadget, role):
    """The model, the COCO regressor and the GMM prior all go through the same loader."""
    good_model = tmp_path / "smpl.npz"
    np.savez(good_model, **_made_up_smpl(rng))
    good_regressor = tmp_path / "coco.npy"
    np.save(good_regressor, np.full((17, V_SMALL), 1.0 / V_SMALL))
    path, marker, expected = _hostile_file(tmp_path, gadget, f"{role}.pkl")
    files = {"model": good_model, "regressor": good_regressor, "gmm": ""} | {role: path}
    with pytest.raises(SmplFileError) as excinfo:
        SmplBody.from_config(_smpl_config(tmp_path, files["model"], files["regressor"], files["gmm"]))
    _assert_refused(excinfo, path, expected, marker)


@pytest.mark.parametrize("gadget", sorted(GADGETS))
def test_load_body_model_refuses(tmp_path, gadget):
    path, marker, expected = _hostile_file(tmp_path, gadget)
    with pytest.raises(SmplFileError) as excinfo:
        load_body_model("smpl", _smpl_config(tmp_path, path))
    _assert_refused(excinfo, path, expected, marker)


@pytest.mark.parametrize("gadget", ["exec", "getattr_chain"])
def test_replay_with_hostile_params_refuses(tmp_path, gadget):
    """`smplify3d replay BAG --params FILE` with an SMPL model path in the params file."""
    from smplify3d_ros.replay import replay_bag

    path, marker, expected = _hostile_file(tmp_path, gadget)
    params = tmp_path / "params.yaml"
    params.write_text(yaml.safe_dump({"fitting": {"body": {"model": "smpl", "smpl_model_path": str(path)}}}))
    bag = Path(__file__).resolve().parents[1] / "bags" / "walk"
    with pytest.raises(SmplFileError) as excinfo:
        replay_bag(bag, tmp_path / "out.mcap", params, progress=False, max_frames=1)
    _assert_refused(excinfo, path, expected, marker)


def test_codecs_encode_only_for_latin1(tmp_path):
    """`_codecs.encode` is allowed for the byte strings protocol-2 files hold, with no other codec."""
    path = tmp_path / "model.pkl"
    path.write_bytes(b"c_codecs\nencode\n(Vx\nVzlib_codec\ntR.")
    with pytest.raises(SmplFileError, match=f"^{path}: refusing _codecs.encode with codec 'zlib_codec'$"):
        load_arrays(path)


def test_a_loader_function_cannot_be_modified(tmp_path):
    """BUILD on an allowed function would set its attributes for the whole process: refused."""
    path = tmp_path / "model.pkl"
    path.write_bytes(b"ccopy_reg\n_reconstructor\n(dS'__defaults__'\nI1\nsb.")
    with pytest.raises(SmplFileError, match=f"^{path}: an SMPL file tried to modify a loader function$"):
        load_arrays(path)


@pytest.mark.parametrize("gadget", sorted(GADGETS))
def test_smpl_to_npz_refuses(tmp_path, capsys, gadget):
    """The converter reads through the same loader: exit code 2, one line naming the object, no output."""
    from smplify3d_ros.cli import main

    path, marker, expected = _hostile_file(tmp_path, gadget)
    assert main(["smpl-to-npz", str(path)]) == 2
    err = capsys.readouterr().err
    assert err == f"smplify3d smpl-to-npz: refusing to load {expected} from {path}: SMPL files hold only arrays\n"
    assert not marker.exists() and not path.with_suffix(".npz").exists()
