"""Parameter files: vocabulary, validation messages, TOML round trip, transforms."""

import re

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import bsfs_jax as bsfs
from bsfs_jax.params import KEYS, ParameterError, validate

from .helpers import tree_allclose


def _write(tmp_path, text, name="params.toml"):
    path = tmp_path / name
    path.write_text(text)
    return path


def _load_error(tmp_path, text) -> str:
    with pytest.raises(ParameterError) as info:
        bsfs.load_params(_write(tmp_path, text))
    return str(info.value)


# --------------------------------------------------------------------------------------
# Vocabulary errors
# --------------------------------------------------------------------------------------
def test_unknown_key_did_you_mean(tmp_path):
    msg = _load_error(tmp_path, "[nut]\npreload_nn = 1500.0\n")
    assert "unknown key 'preload_nn'" in msg and "[nut]" in msg
    assert "Did you mean 'preload_n'" in msg
    assert "params.toml" in msg  # names the file


def test_unknown_key_far_from_anything(tmp_path):
    msg = _load_error(tmp_path, "[bearing]\nzzz = 1.0\n")
    assert "unknown key 'zzz'" in msg and "Did you mean" not in msg
    assert "Allowed keys in [bearing]" in msg and "preload_n" in msg


def test_unknown_section(tmp_path):
    msg = _load_error(tmp_path, "[nutt]\npreload_n = 1500.0\n")
    assert "unknown section [nutt]" in msg and "Did you mean [nut]" in msg


def test_unknown_preset_base(tmp_path):
    msg = _load_error(tmp_path, 'base = "defualt"\n')
    assert "unknown preset 'defualt'" in msg and "Did you mean 'default'" in msg
    with pytest.raises(ParameterError, match="unknown preset"):
        bsfs.preset("no-such-preset")


def test_unknown_name_in_replace():
    with pytest.raises(ParameterError, match=r"unknown parameter 'nut\.preload'.*nut\.preload_n"):
        bsfs.preset().replace("nut.preload", 1.0)


@pytest.mark.parametrize("value", ['"high"', "[1.0, 2.0]", "true", "{ a = 1 }"])
def test_non_number(tmp_path, value):
    msg = _load_error(tmp_path, f"[nut]\npreload_n = {value}\n")
    assert "'nut.preload_n' must be a number" in msg


def test_bool_key_must_be_bool(tmp_path):
    msg = _load_error(tmp_path, "[thermal]\nenabled = 1\n")
    assert "'thermal.enabled' must be true or false" in msg


@pytest.mark.parametrize("value", ["nan", "inf", "-inf"])
def test_non_finite(tmp_path, value):
    msg = _load_error(tmp_path, f"[masses]\nnut_kg = {value}\n")
    assert "'masses.nut_kg'" in msg and ("not finite" in msg or "outside" in msg)


# --------------------------------------------------------------------------------------
# Range errors: the message names the key, the value and the allowed range
# --------------------------------------------------------------------------------------
RANGE_CASES = [
    ("masses", "bearing_kg", 0.0, "(0, inf)"),
    ("masses", "screw_kg", -1.0, "(0, inf)"),
    ("masses", "nut_kg", 0.0, "(0, inf)"),
    ("nut", "contact_angle_deg", 0.0, "(0, 90)"),
    ("nut", "contact_angle_deg", 90.0, "(0, 90)"),
    ("nut", "contact_angle_deg", -10.0, "(0, 90)"),
    ("bearing", "contact_angle_deg", 95.0, "(0, 90)"),
    ("nut", "conformity_screw", 0.5, "(0.5, 1]"),
    ("nut", "conformity_nut", 0.45, "(0.5, 1]"),
    ("bearing", "conformity_inner", 0.5, "(0.5, 1]"),
    ("bearing", "conformity_outer", 0.3, "(0.5, 1]"),
    ("nut", "preload_n", 0.0, "(0, inf)"),
    ("bearing", "preload_n", -100.0, "(0, inf)"),
    ("nut", "balls", 0.5, "[1, inf)"),
    ("bearing", "balls", 0.0, "[1, inf)"),
    ("damping", "nut_n_s_per_m", -1.0, "[0, inf)"),
    ("screw", "poisson_ratio", 0.5, "(0, 0.5)"),
]


@pytest.mark.parametrize("section,key,value,allowed", RANGE_CASES)
def test_out_of_range_values(tmp_path, section, key, value, allowed):
    msg = _load_error(tmp_path, f"[{section}]\n{key} = {value}\n")
    assert f"'{section}.{key}'" in msg
    assert f"= {value:g}" in msg
    assert f"allowed range {allowed}" in msg


@pytest.mark.parametrize("section,key,value,allowed", RANGE_CASES[:8])
def test_validate_catches_replaced_values(section, key, value, allowed):
    """Values set programmatically (not from a file) are checked by `validate`."""
    params = bsfs.preset().replace(f"{section}.{key}", value)
    with pytest.raises(ParameterError, match=re.escape(allowed)):
        validate(params)


def test_boundary_values_accepted(tmp_path):
    params = bsfs.load_params(_write(tmp_path, "[nut]\nballs = 1.0\nconformity_nut = 1.0\n"
                                     "contact_angle_deg = 89.9\n[damping]\nnut_n_s_per_m = 0\n"))
    assert float(params.nut.balls) == 1.0 and float(params.damping.nut) == 0.0


def test_cross_key_rule(tmp_path):
    msg = _load_error(tmp_path, "[nut]\npitch_diameter_mm = 3.0\n")
    assert "'nut.pitch_diameter_mm' must exceed 'nut.ball_diameter_mm'" in msg


def test_malformed_toml(tmp_path):
    msg = _load_error(tmp_path, "[nut\npreload_n = 1500\n")
    assert "not valid TOML" in msg and "params.toml" in msg


def test_missing_file(tmp_path):
    with pytest.raises(ParameterError, match="cannot read parameter file .*nowhere.toml"):
        bsfs.load_params(tmp_path / "nowhere.toml")


def test_missing_key_in_full_dict():
    data = bsfs.preset().to_dict()
    del data["nut"]["preload_n"]
    with pytest.raises(ParameterError, match=r"missing key 'nut\.preload_n'"):
        bsfs.BallScrewParams.from_dict(data)


def test_parameter_error_is_value_error():
    assert issubclass(ParameterError, ValueError)


# --------------------------------------------------------------------------------------
# Round trip and partial files
# --------------------------------------------------------------------------------------
def test_every_key_documented_once():
    names = [k.name for k in KEYS]
    assert len(names) == len(set(names))
    text = bsfs.params_to_toml(bsfs.preset())
    for key in KEYS:
        assert re.search(rf"^#? ?{re.escape(key.key)} = ", text, re.M), key.name


@pytest.mark.parametrize("changes", [
    {},
    {"nut.preload_n": 2000.0, "thermal.enabled": False, "bearing.balls": 13.0},
    {"nut.hertz_k_m_per_n23": 3.9e-7, "thermal.nut_offset_um": -0.25,
     "thermal.bearing_offset_um": 0.069, "screw.stiffness_n_per_um": 300.0},
])
def test_toml_round_trip(tmp_path, changes):
    params = bsfs.preset()
    for name, value in changes.items():
        params = params.replace(name, value)
    text = bsfs.params_to_toml(params, header="round trip\ntest")
    loaded = bsfs.load_params(_write(tmp_path, text))
    assert tree_allclose(loaded, params, rtol=1e-15, atol=0.0)
    assert loaded.thermal.enabled == params.thermal.enabled
    # save_params: atomic write, refuses to overwrite unless asked.
    path = tmp_path / "saved.toml"
    bsfs.save_params(params, path)
    with pytest.raises(FileExistsError):
        bsfs.save_params(params, path)
    bsfs.save_params(params, path, overwrite=True)
    assert tree_allclose(bsfs.load_params(path), params, rtol=1e-15, atol=0.0)


def test_partial_file_and_overrides(tmp_path):
    path = _write(tmp_path, "[nut]\npreload_n = 1000.0\n")
    params = bsfs.load_params(path, overrides={"thermal": {"speed_rpm": 3000.0}})
    assert float(params.get("nut.preload_n")) == 1000.0
    assert float(params.get("thermal.speed_rpm")) == 3000.0
    # Everything else comes from the default preset (in SI inside).
    np.testing.assert_allclose(float(params.nut.ball_diameter), 3.175e-3, rtol=1e-15)
    np.testing.assert_allclose(float(params.nut.contact_angle), np.pi / 4, rtol=1e-15)


def test_default_preset_matches_physics_md():
    p = bsfs.preset()
    expected = {"masses.bearing_kg": 0.5, "masses.screw_kg": 1.44, "masses.nut_kg": 1.5,
                "nut.balls": 50, "nut.ball_diameter_mm": 3.175, "nut.contact_angle_deg": 45,
                "nut.preload_n": 1500, "bearing.balls": 16, "bearing.contact_angle_deg": 40,
                "screw.youngs_modulus_gpa": 206, "thermal.speed_rpm": 2000,
                "thermal.expansion_per_k": 11.6e-6}
    for name, value in expected.items():
        np.testing.assert_allclose(float(p.get(name)), value, rtol=1e-14, err_msg=name)
    assert p.thermal.enabled is True
    assert "default" in bsfs.list_presets()


# --------------------------------------------------------------------------------------
# Parameters under transforms
# --------------------------------------------------------------------------------------
def test_replace_under_jit_grad_and_vmap():
    params = bsfs.preset()

    @eqx.filter_jit
    def preload_distance(p, value):
        return bsfs.build_system(p.replace("nut.preload_n", value)).nut.a

    eager = bsfs.build_system(params.replace("nut.preload_n", 2000.0)).nut.a
    np.testing.assert_allclose(preload_distance(params, jnp.asarray(2000.0)), eager, rtol=1e-14)
    many = jax.vmap(preload_distance, in_axes=(None, 0))(params, jnp.array([1000.0, 2000.0]))
    np.testing.assert_allclose(many[1], eager, rtol=1e-14)
    assert float(many[0]) < float(many[1])
    # d A / d F_p = (2/3) K Q0^(2/3) / F_p (A = A0 + K (F_p / (Z sin b cos l))^(2/3)).
    grad = jax.grad(lambda v: preload_distance(params, v))(jnp.asarray(1500.0))
    delta0 = float(bsfs.build_system(params).nut.a - bsfs.build_system(params).nut.a0)
    np.testing.assert_allclose(float(grad), 2.0 / 3.0 * delta0 / 1500.0, rtol=1e-12)
    # Ball counts are real-valued and differentiable too.
    dballs = jax.grad(lambda z: bsfs.build_system(params.replace("nut.balls", z)).nut.a)(50.0)
    assert float(dballs) < 0.0


def test_get_returns_file_units():
    p = bsfs.preset()
    np.testing.assert_allclose(float(p.get("nut.contact_angle_deg")), 45.0, rtol=1e-14)
    np.testing.assert_allclose(float(p.get("screw.youngs_modulus_gpa")), 206.0, rtol=1e-14)
    assert p.get("nut.hertz_k_m_per_n23") is None
