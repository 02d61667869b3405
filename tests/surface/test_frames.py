"""surface.frames.axis_frame: orthonormal, right-handed, the axis last, identity for z."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from surface.frames import axis_frame

finite = st.floats(-1e3, 1e3, allow_nan=False)


@given(st.tuples(finite, finite, finite).filter(lambda v: np.linalg.norm(v) > 1e-6),
       st.integers(-5, 5))
@settings(max_examples=200, deadline=None)
def test_frame_is_orthonormal_right_handed_with_the_axis_last(axis, turns):
    frame = axis_frame(axis, turns)
    np.testing.assert_allclose(frame @ frame.T, np.eye(3), atol=1e-14)
    assert np.linalg.det(frame) == pytest.approx(1.0, abs=1e-14)
    np.testing.assert_allclose(frame[2], np.asarray(axis) / np.linalg.norm(axis), atol=1e-15)


def test_frame_of_z_is_the_identity_and_quarter_turns_are_exact():
    np.testing.assert_array_equal(axis_frame([0.0, 0.0, 2.0]), np.eye(3))
    base = axis_frame([0.3, -1.2, 0.7])
    turned = axis_frame([0.3, -1.2, 0.7], 1)
    np.testing.assert_array_equal(turned[0], base[1])   # (e2, -e1): bit for bit
    np.testing.assert_array_equal(turned[1], -base[0])
    np.testing.assert_array_equal(axis_frame([0.3, -1.2, 0.7], -1)[0], -base[1])
    np.testing.assert_array_equal(axis_frame([0.3, -1.2, 0.7], 4), base)


def test_frame_agrees_with_the_three_former_conventions():
    """Gram-Schmidt of the least-aligned world axis (sections), and the cross-product forms
    (``e1 = helper x a``: one quarter turn back; ``e1 = a x helper``: one forward)."""
    rng = np.random.default_rng(3)
    for a in rng.normal(size=(50, 3)):
        a = a / np.linalg.norm(a)
        helper = np.eye(3)[int(np.argmin(np.abs(a)))]
        e1 = np.cross(helper, a)
        e1 /= np.linalg.norm(e1)
        np.testing.assert_allclose(axis_frame(a, -1), np.stack([e1, np.cross(a, e1), a]),
                                   atol=1e-15)
        e1 = np.cross(a, helper)
        e1 /= np.linalg.norm(e1)
        np.testing.assert_allclose(axis_frame(a, 1), np.stack([e1, np.cross(a, e1), a]),
                                   atol=1e-15)


@pytest.mark.parametrize("axis", [[0.0, 0.0, 0.0], [np.nan, 0.0, 1.0], [1.0, 2.0]])
def test_bad_axis_is_refused(axis):
    with pytest.raises(ValueError, match="axis"):
        axis_frame(axis)
