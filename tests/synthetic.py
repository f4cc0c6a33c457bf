"""Scenes built directly as SceneData arrays, for core tests that need no bpy scene."""
import numpy as np


def grid_quad(n, size=1.0):
    """A square z = size in [-size, size]^2, n x n quads, two triangles each."""
    u = np.linspace(-size, size, n + 1)
    x, y = np.meshgrid(u, u)
    p = np.stack([x, y, np.full_like(x, size)], -1).reshape(-1, 3)
    i = np.arange((n + 1) ** 2).reshape(n + 1, n + 1)
    a, b, c, d = i[:-1, :-1].ravel(), i[:-1, 1:].ravel(), i[1:, 1:].ravel(), i[1:, :-1].ravel()
    return p[np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)])]


def closed_box(n=4, size=1.0):
    """The six faces of a cube of side 2*size, each an n x n grid."""
    face = grid_quad(n, size)
    rotations = [np.eye(3), np.diag([1, -1, -1]),
                 np.array([[0, 0, 1], [0, 1, 0], [-1, 0, 0]]),
                 np.array([[0, 0, -1], [0, 1, 0], [1, 0, 0]]),
                 np.array([[1, 0, 0], [0, 0, 1], [0, -1, 0]]),
                 np.array([[1, 0, 0], [0, 0, -1], [0, 1, 0]])]
    return np.concatenate([face @ r.T for r in rotations]).astype(np.float32)


def flat_normals(triangles):
    n = np.cross(triangles[:, 1] - triangles[:, 0], triangles[:, 2] - triangles[:, 0])
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    return np.repeat(n[:, None], 3, 1).astype(np.float32)


def scene(sd, triangles, albedo, emission=(0, 0, 0), lights=(), world=(0, 0, 0),
          camera=None, normals=None):
    """SceneData with one material on every triangle; `sd` is the scene_data module."""
    t = len(triangles)
    mesh = sd.Mesh(triangles.astype(np.float32),
                   flat_normals(triangles) if normals is None else normals,
                   np.zeros(t, np.int32), np.zeros(t, np.int32), ["mesh"], np.zeros(1, bool))
    mats = sd.Materials(np.array([albedo], np.float32).reshape(1, 3),
                        np.array([emission], np.float32).reshape(1, 3), ["material"])
    return sd.SceneData(mesh, mats, list(lights), np.array(world, np.float64), camera)


def camera(sd, matrix=None, size=32, projection='PERSP', lens=20.0, ortho_scale=2.0):
    m = np.eye(4) if matrix is None else np.asarray(matrix, np.float64)
    return sd.Camera(m, projection, lens, 36.0, 24.0, 'AUTO', ortho_scale, 0.0, 0.0,
                     1e-3, 1e4, size, size)
