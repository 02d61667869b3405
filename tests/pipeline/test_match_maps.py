"""pipeline.match_maps: the disparity, σ and status maps of a matched pair."""

from __future__ import annotations

from contextlib import ExitStack

import cv2
import numpy as np
import pytest

from matching.pair import AMBIGUOUS, APERTURE, PAIR_STATUS_NAMES, PairMatches
from pipeline.match_maps import (
    NO_CANDIDATE,
    STATUS_COLOURS,
    STATUS_MEANINGS,
    map_arrays,
    write_maps,
)


def _matches(w=64, h=48, spacing=4):
    ys, xs = np.mgrid[2:h:spacing, 2:w:spacing]
    xl = np.column_stack([xs.ravel(), ys.ravel()]).astype(np.float64)
    n = len(xl)
    status = np.zeros(n, np.uint8)
    status[xl[:, 0] > 40] = APERTURE  # a band rejected as ill-conditioned
    status[(xl[:, 1] < 10) & (xl[:, 0] <= 40)] = AMBIGUOUS
    disparity = 5.0 + 0.1 * xl[:, 0]
    xr = xl - np.column_stack([disparity, np.zeros(n)])
    cov = np.zeros((n, 2, 2))
    cov[:, 0, 0] = (0.01 * (1 + xl[:, 1] / h)) ** 2
    nan = np.full(n, np.nan)
    return PairMatches(
        x_left=xl, x_right=xr, approx=xr, cov=cov, sigma=np.sqrt(cov[:, 0, 0] / 2),
        sigma0=nan, correlation=nan, iterations=np.zeros(n, np.int32),
        affine=np.full((n, 6), np.nan), radiometric=np.full((n, 2), np.nan),
        patch=np.full(n, 15, np.int32), texture=nan, status=status, rectified=False,
        image_size=(w, h), offset=np.zeros((n, 2)), edge=np.zeros(n, bool))


def test_arrays_hold_each_candidate():
    m = _matches()
    a = map_arrays(m)
    xi = m.x_left.astype(int)
    ok = m.status == 0
    assert a["status"].shape == (48, 64)
    assert np.array_equal(a["status"][xi[:, 1], xi[:, 0]], m.status)
    assert (a["status"] != NO_CANDIDATE).sum() == len(m)
    d = a["disparity"][xi[:, 1], xi[:, 0]]
    assert np.allclose(d[ok], m.x_left[ok, 0] - m.x_right[ok, 0])
    assert np.isnan(d[~ok]).all()
    s = a["sigma"][xi[:, 1], xi[:, 0]]
    assert np.allclose(s[ok], np.sqrt(m.cov[ok, 0, 0]))


@pytest.mark.parametrize("staged", [False, True])
def test_written_files_and_status_colours(tmp_path, staged):
    m = _matches()
    if staged:
        with ExitStack() as stack:
            paths = write_maps(tmp_path, m, prefix="c.", stack=stack)
            assert not any(p.exists() for p in paths)  # renamed only when the stack closes
    else:
        paths = write_maps(tmp_path, m, prefix="c.")
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(p.name for p in paths)
    status_png = cv2.imread(str(tmp_path / "c.status.png"))
    # the image part (left of the legend panel) shows the aperture band in its colour
    assert status_png.shape[0] >= 48 and status_png.shape[1] > 64
    assert tuple(status_png[20, 50]) == STATUS_COLOURS[APERTURE]
    assert tuple(status_png[20, 10]) == STATUS_COLOURS[0]
    assert np.array_equal(np.load(tmp_path / "c.status.npy"), map_arrays(m)["status"])
    # the page shows the three maps and every status present with its count and meaning
    page = (tmp_path / "c.report.html").read_text(encoding="utf-8")
    assert page.count("<img ") == 3 and page.count("data:image/png;base64,") == 3
    for code in np.unique(m.status):
        count = int((m.status == code).sum())
        assert (f"<td>{PAIR_STATUS_NAMES[int(code)]}</td><td style='text-align:right'>"
                f"{count}</td>") in page
        assert STATUS_MEANINGS[int(code)].split(" (")[0] in page


def test_every_status_has_a_meaning():
    assert set(STATUS_MEANINGS) == set(PAIR_STATUS_NAMES)


def test_a_failed_write_leaves_nothing(tmp_path):
    m = _matches()
    with pytest.raises(RuntimeError), ExitStack() as stack:
        write_maps(tmp_path, m, stack=stack)
        raise RuntimeError("the cloud failed")
    assert list(tmp_path.iterdir()) == []
