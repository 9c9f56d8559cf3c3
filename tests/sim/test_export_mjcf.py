"""``microg export-mjcf``: the exported model's pad is the rig's pad for what the foot carries at home."""

from pathlib import Path

import mujoco
import numpy as np
import pytest

from microg_env.cli import main
from microg_env.envs.landing import MicroGravityLandingEnv
from microg_env.params import RigParams
from microg_env.sim.model import MAX_TEMPLATE_BYTES, build_rig, pad_contact_solref

LOADS_KG = ("1.0", "5.2")  # 6.2 kg of weights, held off the lander at home


def test_the_exported_pad_is_the_lander_alone_s_while_the_weights_are_held_off(tmp_path):
    """The home keyframe holds the weights off, so the pad's solref is the lander's (K and D were
    1 % low with 6.2 kg of weights when it was the lander's plus the weights')."""
    exported = tmp_path / "rig.xml"
    assert main(["export-mjcf", str(exported), *(f"--load={kg}" for kg in LOADS_KG)]) == 0
    model = mujoco.MjModel.from_xml_path(str(exported))
    params = RigParams()
    pad_contacts = build_rig(params).pad_contacts
    alone, _ = pad_contact_solref(
        params.pad.stiffness_n_per_m,
        params.pad.damping_n_s_per_m,
        params.lander.mass_kg,
        pad_contacts,
        params.pad.impedance,
    )
    solref = model.geom_solref[model.geom("pad").id]
    np.testing.assert_allclose(solref, alone, rtol=1e-5)  # MJCF keeps 6 digits; the fault was 1 %
    assert model.body("load_0").mass == 0.0  # the weights are held off in the exported model


def test_a_template_over_the_size_cap_or_not_a_regular_file_is_refused(tmp_path):
    huge = tmp_path / "huge.xml"
    with huge.open("wb") as stream:
        stream.truncate(MAX_TEMPLATE_BYTES + 1)  # sparse: no disk used
    with pytest.raises(ValueError, match=r"xml_file .*huge\.xml.* at most \d+ bytes"):
        MicroGravityLandingEnv(xml_file=str(huge))


def _fields(model: mujoco.MjModel) -> dict[str, np.ndarray]:
    """Every numeric array of a compiled model (its names are in ``names``)."""
    fields = {}
    for name in dir(model):
        value = getattr(model, name, None)
        if isinstance(value, np.ndarray) and value.dtype.kind in "fiub":
            fields[name] = value
    return fields


def test_the_repositorys_mjcf_is_export_mjcfs_output_for_the_paper_s_rig(tmp_path):
    """mjcf/scene.xml (the repository's resolved rig, for MuJoCo's viewer) is what
    ``microg export-mjcf`` writes for the paper's rig: the same elements, names and every numeric
    field to MJCF's six digits. Regenerate it with ``microg export-mjcf mjcf/scene.xml``."""
    shipped = Path(__file__).resolve().parents[2] / "mjcf" / "scene.xml"
    exported = tmp_path / "scene.xml"
    assert main(["export-mjcf", str(exported)]) == 0
    ours, theirs = mujoco.MjModel.from_xml_path(str(shipped)), mujoco.MjModel.from_xml_path(str(exported))
    assert (ours.nbody, ours.njnt, ours.nu, ours.ntendon, ours.nsensor, ours.nkey) == (3, 2, 2, 1, 5, 1)
    assert ours.names == theirs.names
    ours_fields, theirs_fields = _fields(ours), _fields(theirs)
    assert ours_fields.keys() == theirs_fields.keys()
    for name, value in ours_fields.items():
        np.testing.assert_allclose(value, theirs_fields[name], rtol=1e-5, atol=1e-12, err_msg=name)
    assert ours.geom_solref[ours.geom("pad").id, 0] < 0  # the computed pad contact, not MuJoCo's default
    assert ours.jnt_stiffness[ours.joint("qzs").id] == RigParams().qzs.residual_stiffness_n_per_m
