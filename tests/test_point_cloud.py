"""Point clouds: local Delaunay triangles (tufted cover) and the same ADMM on them.

Checked against the exact geodesic distance on the unit sphere and against the mesh solve
of the surface the points were sampled from.
"""

import numpy as np
import pytest
import trimesh

import warp_regdist as wrd
from warp_regdist.geometry.point_cloud import _one_rings


def _fibonacci_sphere(p):
    i = np.arange(p) + 0.5
    z = 1 - 2 * i / p
    r = np.sqrt(1 - z * z)
    phi = np.pi * (1 + 5 ** 0.5) * i
    return np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=1)


def test_one_ring_of_a_regular_hexagon_is_its_six_triangles():
    t = np.arange(6) * np.pi / 3
    P = np.concatenate([[[0.0, 0.0, 0.0]], np.stack([np.cos(t), np.sin(t), 0 * t], axis=1),
                        2.5 * np.stack([np.cos(t + 0.3), np.sin(t + 0.3), 0 * t], axis=1)])
    nbr = np.argsort(np.linalg.norm(P[:, None] - P[None], axis=2), axis=1)
    rings = _one_rings(P, nbr)
    rings = rings[rings[:, 0] == 0]
    assert sorted(map(tuple, np.sort(rings, axis=1))) == sorted((0,) + tuple(sorted((1 + i, 1 + (i + 1) % 6)))
                                                               for i in range(6))


def test_sphere_cloud_area_and_geodesic_distance():
    P = _fibonacci_sphere(4000)
    cloud = wrd.PointCloud(P)
    area = cloud.element_volumes @ cloud.element_weights
    assert area == pytest.approx(4 * np.pi, rel=0.01)
    res = wrd.DistanceSolver(cloud, alpha_hat=0.0).solve([0])
    exact = np.arccos(np.clip(P @ P[0], -1, 1))
    far = exact > 0.3
    assert res.converged and res.distance.shape == (4000,)
    # the discrete distance at alpha 0 on the 2,562-vertex icosphere is 1.8% off; the cloud 2.4%
    assert np.median(np.abs(res.distance[far] - exact[far]) / exact[far]) < 0.03


def test_spot_cloud_matches_the_mesh_solve():
    mesh = wrd.load_mesh(wrd.data_path("spot_rr.off"))
    P, _ = trimesh.sample.sample_surface(trimesh.Trimesh(mesh.vertices, mesh.faces, process=False), 6000, seed=1)
    cloud = wrd.PointCloud(P)
    at = wrd.surface_points(mesh, P)
    u_mesh = wrd.DistanceSolver(mesh, alpha_hat=0.05).solve(points=at[:1]).distance
    expected = np.array([np.asarray(b) @ u_mesh[mesh.faces[f]] for f, b in at])
    u = wrd.DistanceSolver(cloud, alpha_hat=0.05).solve([0]).distance
    far = expected > 0.05 * expected.max()
    assert np.median(np.abs(u[far] - expected[far]) / expected[far]) < 0.02
    assert np.abs(u - expected).max() < 0.03 * expected.max()


@pytest.mark.parametrize("points, message", [
    (np.zeros((0, 3)), r"expected points of shape \(p, 3\) with p >= 3, got shape \(0, 3\)"),
    ([[0, 0, 0], [1, 0, 0]], r"expected points of shape \(p, 3\) with p >= 3, got shape \(2, 3\)"),
    ([[0, 0, 0], [1, 0, np.nan], [0, 1, 0], [1, 1, 0]], r"expected finite points, got 1 points with NaN/inf \(first: point 1\)"),
    ([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 0, 0]], r"expected distinct points, got points 1 and 3 at the same place"),
])
def test_bad_clouds(points, message):
    with pytest.raises(ValueError, match=message):
        wrd.PointCloud(points)


def test_cloud_is_refused_where_faces_are_needed():
    cloud = wrd.PointCloud(_fibonacci_sphere(200))
    with pytest.raises(ValueError, match="expected a triangle or tetrahedral mesh for surface_points, got a PointCloud"):
        wrd.surface_points(cloud, [[1, 0, 0]])
    with pytest.raises(ValueError, match=r"expected a triangle mesh for points of column 0, got a PointCloud"):
        wrd.DistanceSolver(cloud).solve(points=[(0, (1, 0, 0))])
    with pytest.raises(ValueError, match=r"expected regularizer 'dirichlet' for a PointCloud .* got 'hessian'"):
        wrd.DistanceSolver(cloud, 1e-3, regularizer="hessian")


def test_cli_reads_point_files(tmp_path, capsys):
    from warp_regdist.cli import main

    P = _fibonacci_sphere(500)
    np.savetxt(tmp_path / "cloud.xyz", P)
    np.save(tmp_path / "cloud.npy", P)
    trimesh.PointCloud(P).export(tmp_path / "cloud.ply")
    outputs = []
    for name in ("cloud.xyz", "cloud.npy", "cloud.ply"):
        out = tmp_path / (name + ".out.npy")
        assert main(["distance", str(tmp_path / name), "--sources", "0", "--output", str(out)]) == 0
        assert f"{name}: 500 points, " in capsys.readouterr().out
        outputs.append(np.load(out))
    # the PLY holds float32 coordinates (3e-8 away), which move the distances by about 2e-5
    assert np.allclose(outputs[0], outputs[1], atol=1e-12) and np.allclose(outputs[0], outputs[2], atol=1e-4)
    (tmp_path / "bad.xyz").write_text("1 2 3\n4 5 6\n")
    assert main(["distance", str(tmp_path / "bad.xyz"), "--sources", "0", "--output", str(out)]) == 2
    assert "expected points of shape (p, 3) with p >= 3, got shape (2, 3) in" in capsys.readouterr().err
