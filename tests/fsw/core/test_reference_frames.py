"""Each map cell's source view and its pose error (fsw.core.map.reference_frames; issue 13): the
better-placed view owns a cell, a rigid-motion covariance moves between centres with its
lever, and the state survives a checkpoint; the station chain then merges a registered view
with the reference's error in place of the chained frame."""

from __future__ import annotations

import json
import math

import numpy as np

from fsw.core.geometry import CameraPose
from fsw.core.map.reference_frames import ReferenceFrames, about
from fsw.core.registration.registration import Registration, RegistrationConfig
from fsw.core.registration.station_chain import StationChain


def test_the_better_placed_view_owns_a_cell() -> None:
    f = ReferenceFrames((4, 5))
    xyz = np.array([[1.0, 0.0, 0.0], [2.0, 0.0, 0.0], [3.0, 0.0, 0.0]])
    poor = np.diag([math.radians(2.0) ** 2] * 3 + [0.10**2] * 3)
    good = np.diag([math.radians(0.1) ** 2] * 3 + [0.005**2] * 3)
    f.add(np.array([0, 1, 2]), xyz, np.zeros(3), poor)
    f.add(np.array([1, 2, 3]), np.vstack([xyz[1:], [[4.0, 0.0, 0.0]]]), np.zeros(3), good)
    f.add(np.array([2]), xyz[2:], np.zeros(3), poor)  # worse than the owner: no change
    assert f.sources(np.array([0, 1, 2, 3, 4])).tolist() == [0, 1, 1, 1, -1]
    # the score is the displacement variance at the cell: position plus rotation times lever
    assert f.score.reshape(-1)[0] == np.float32(3 * 0.1**2 + 2 * math.radians(2.0) ** 2 * 1.0)
    f.add(np.array([4]), np.zeros((1, 3)), np.zeros(3), np.full((6, 6), np.nan))  # ignored
    assert f.sources(np.array([4])).tolist() == [-1] and len(f.covs) == 2


def test_a_rigid_motion_covariance_carries_its_lever() -> None:
    """A yaw error about one centre is, about a centre 2 m along x, the same yaw with a
    sideways translation of 2 m times the yaw."""
    s = math.radians(1.0)
    cov = np.diag([0.0, 0.0, s**2, 0.0, 0.0, 0.0])
    moved = about(cov, np.zeros(3), np.array([2.0, 0.0, 0.0]))
    assert math.sqrt(moved[4, 4]) == np.float64(2.0 * s) or abs(math.sqrt(moved[4, 4]) - 2.0 * s) < 1e-12
    assert abs(moved[2, 4]) == abs(2.0 * s**2) and moved[3, 3] == 0.0


def test_the_sources_survive_a_checkpoint_and_bad_state_leaves_none() -> None:
    f = ReferenceFrames((3, 3))
    f.add(np.array([4, 5]), np.array([[1.0, 1.0, 0.0], [1.0, 2.0, 0.0]]), np.array([0.0, 0.0, 1.0]),
          np.eye(6) * 1e-4)
    g = ReferenceFrames((3, 3))
    g.restore(json.loads(json.dumps(f.state())))
    np.testing.assert_array_equal(g.owner, f.owner)
    np.testing.assert_array_equal(g.score, f.score)
    np.testing.assert_allclose(g.covs[0], f.covs[0])
    h = ReferenceFrames((4, 4))  # another grid: not used
    h.restore(f.state())
    assert (h.owner == -1).all() and h.covs == []
    h.restore({"owner": "not base64"})
    assert (h.owner == -1).all()


def test_a_registered_view_carries_the_references_error_not_the_chained_frame() -> None:
    """With the reference's own error in the correction's covariance, the merge uses it
    instead of adding the chained frame again; the confirmation compares the views relative
    to the map (their common reference error left out)."""
    chain = StationChain()
    cfg = RegistrationConfig()
    pose = CameraPose(np.eye(3), np.array([1.0, 2.0, 1.5]))
    anchor = np.eye(6) * 1e-4
    chain.reference(anchor)
    rel = np.eye(6) * 1e-6
    ref_err = np.eye(6) * 4e-4
    vp = chain.prior(pose, np.eye(6) * 1e-3, 0, cfg)
    reg = Registration("registered", correction=np.zeros(6), cov=rel + ref_err, ref_cov=ref_err)
    _, merged, nav = chain.registered(pose, np.eye(6) * 1e-3, 0, 0.0, vp, reg, cfg)
    np.testing.assert_allclose(merged, rel + ref_err)  # no anchor added on top
    assert nav is None  # one view alone is never fed back
    vp2 = chain.prior(pose, np.eye(6) * 1e-3, 0, cfg)
    assert vp2.same_station
    inc = np.r_[0.0, 0.0, 0.006, 0.006, 0.0, 0.0]  # 6 mrad, 6 mm: chi2 36 relative to the map
    reg2 = Registration("registered", correction=inc, cov=rel + ref_err, ref_cov=ref_err)
    _, _, nav2 = chain.registered(pose, np.eye(6) * 1e-3, 0, 0.0, vp2, reg2, cfg)
    assert nav2 is None  # relative to the map the second view disagrees: not confirmed
    # the old covariance (reference error counted as if relative) would have confirmed it
    i = np.ix_([2, 3, 4, 5], [2, 3, 4, 5])
    m2 = inc[2:] @ np.linalg.solve((2 * (rel + ref_err))[i], inc[2:])
    assert m2 < 18.47
