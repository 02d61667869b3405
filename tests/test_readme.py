"""The README's "Python in ten lines" examples, run exactly as written.

Each ```python block of that section is executed in a fresh folder (with ``fixtures/``
linked in, as in a checkout); the names it defines are then checked against the truth.
"""

from __future__ import annotations

import re

import numpy as np
import pytest

from tests.conftest import ROOT

SECTION = "## Python in ten lines"


def _blocks() -> list[str]:
    text = (ROOT / "README.md").read_text(encoding="utf-8")
    start = text.index(SECTION)
    end = text.index("\n## ", start + len(SECTION))
    return re.findall(r"```python\n(.*?)```", text[start:end], flags=re.S)


def _run(code: str, where, monkeypatch) -> dict:
    (where / "fixtures").symlink_to(ROOT / "fixtures")
    monkeypatch.chdir(where)
    namespace: dict = {"__name__": "__readme__"}
    exec(compile(code, "README.md", "exec"), namespace)  # noqa: S102 - the README's own code
    return namespace


def test_the_section_has_the_two_examples():
    blocks = _blocks()
    assert len(blocks) == 2
    # "ten lines": the statements of each example, imports and comments aside
    for code in blocks:
        statements = [line for line in code.splitlines() if line.strip()
                      and not line.startswith(("import ", "from ", "#", " "))]
        assert len(statements) <= 10


def test_cloud_to_bezier_surface(tmp_path, monkeypatch, capsys):
    ns = _run(_blocks()[0], tmp_path, monkeypatch)
    assert "patches, G1 angle" in capsys.readouterr().out
    assert ns["mesh"].closed
    smooth = ns["smooth"]
    # Loop's construction is G1 up to rounding: the normal angle across patch edges
    assert smooth.g1_angle < 1e-8
    # The wall of the smooth surface against r(z) = 1 + 0.3 sin 2z (the ends are capped
    # flat: z away from them).  Noise: the rings average many points of sigma = 0.002, so
    # less than sigma.  Bias: Loop's surface approximates its control mesh as a cubic
    # B-spline does its polygon, (p[-1] + 4 p[0] + p[1]) / 6, i.e. it sits kappa h^2 / 6
    # inside a curve of curvature kappa sampled every h: along the profile kappa <= 1.2
    # (|r''| = 1.2 |sin 2z|) with h the section spacing, round a ring 1 / r <= 1 / 0.7
    # with h the ring-point spacing on the largest ring.
    v, mesh = smooth.vertices, ns["mesh"]
    section = mesh.section_of_vertex
    ids, counts = np.unique(section[section >= 0], return_counts=True)
    heights = [np.median(mesh.vertices[section == k, 2]) for k in ids]
    h = float(np.median(np.diff(heights)))
    h_ring = 2 * np.pi * 1.3 / counts[1:-1].min()
    bias = (1.2 * h ** 2 + h_ring ** 2 / 0.7) / 6
    wall = (v[:, 2] > 0.2) & (v[:, 2] < 2.8)
    radial = np.hypot(v[wall, 0], v[wall, 1]) - (1 + 0.3 * np.sin(2 * v[wall, 2]))
    assert np.sqrt(np.mean(radial ** 2)) < 0.002 + bias
    from pipeline.export import read_control_net

    net = read_control_net(tmp_path / "vase.npz")
    assert (tmp_path / "vase.ply").is_file()
    # the control net file holds the exact surface: its patches, bit for bit
    np.testing.assert_array_equal(net.control_points, smooth.surface.control_points)


@pytest.mark.slow
def test_image_folder_to_cloud(tmp_path, monkeypatch, capsys):
    """Renders the 24-view 320x240 ring and acquires it (~15 CPU-s)."""
    ns = _run(_blocks()[1], tmp_path, monkeypatch)
    assert "points, median sigma" in capsys.readouterr().out
    from pipeline.cloud_io import read_cloud
    from pipeline.mesh_io import read_mesh
    from surface.metrics import point_mesh_distance

    cloud = ns["cloud"]
    assert len(read_cloud(tmp_path / "ring.ply").points) == len(cloud.points)
    truth = read_mesh(tmp_path / "ring" / "truth" / "mesh.ply")
    distance = point_mesh_distance(cloud.points, *truth)
    # each point's sigma is its predicted error: the median distance to the truth
    # is of that order (a factor 3 leaves room for the model's approximations)
    assert np.median(distance) < 3 * np.median(cloud.sigma)
