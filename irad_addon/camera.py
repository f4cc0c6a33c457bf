"""Camera rays with Blender's conventions: sensor fit, shift, orthographic scale."""
import numpy as np


def view_plane_half_size(cam):
    """Half width and half height of the view plane at unit distance (perspective)
    or in world units (orthographic), following Blender's sensor-fit rules."""
    xasp = cam.width * cam.pixel_aspect_x
    yasp = cam.height * cam.pixel_aspect_y
    fit = cam.sensor_fit
    if fit == 'AUTO':
        fit = 'HORIZONTAL' if xasp >= yasp else 'VERTICAL'
        sensor = cam.sensor_width
    else:
        sensor = cam.sensor_width if fit == 'HORIZONTAL' else cam.sensor_height
    fitted = cam.ortho_scale / 2 if cam.projection == 'ORTHO' else sensor / 2 / cam.lens
    if fit == 'HORIZONTAL':
        return fitted, fitted * yasp / xasp, 2 * fitted
    return fitted * xasp / yasp, fitted, 2 * fitted


def camera_rays(cam, pixel_x, pixel_y):
    """World-space rays through continuous pixel coordinates.

    pixel_x grows to the right from 0 at the left edge, pixel_y grows downwards from
    0 at the top edge (row 0 of our images is the top). Returns origins and unit
    directions, float64 (n, 3), and the cosine between each ray and the view axis
    (to turn hit distance into Blender's Z depth)."""
    half_w, half_h, fitted_size = view_plane_half_size(cam)
    sx = (2.0 * np.asarray(pixel_x, np.float64) / cam.width - 1.0) * half_w + cam.shift_x * fitted_size
    sy = (1.0 - 2.0 * np.asarray(pixel_y, np.float64) / cam.height) * half_h + cam.shift_y * fitted_size
    m = np.asarray(cam.matrix_world, np.float64)
    rot, eye = m[:3, :3], m[:3, 3]
    n = sx.shape[0]
    if cam.projection == 'ORTHO':
        local_origin = np.stack([sx, sy, np.zeros(n)], -1)
        origins = local_origin @ rot.T + eye
        directions = np.broadcast_to(-rot[:, 2], (n, 3)).copy()
        cos_axis = np.ones(n)
    else:
        local_dir = np.stack([sx, sy, -np.ones(n)], -1)
        norm = np.sqrt(sx * sx + sy * sy + 1.0)
        directions = (local_dir / norm[:, None]) @ rot.T
        origins = np.broadcast_to(eye, (n, 3)).copy()
        cos_axis = 1.0 / norm
    return origins, directions, cos_axis


def pixel_samples(width, rows, samples, rng, pixels=None):
    """Continuous pixel coordinates for `samples` rays per pixel of image rows
    rows = (first, stop), or only of `pixels` (indices within those rows): the pixel
    centre for one sample, stratified jitter over the pixel (a box filter) for more.
    Returns (pixel_x, pixel_y, pixel_index within the rows, sample_index), sample-major."""
    if pixels is None:
        pixels = np.arange((rows[1] - rows[0]) * width)
    ys, xs = np.divmod(pixels, width)
    xs = xs.astype(np.float64)
    ys = (ys + rows[0]).astype(np.float64)
    count = xs.size
    if samples == 1:
        offsets = np.full((1, count, 2), 0.5)
    else:
        side = int(np.ceil(np.sqrt(samples)))
        cell = np.arange(samples)
        # Stratified over a side x side grid (the last row partly filled), with a
        # per-pixel random toroidal shift so neighbouring pixels do not share a pattern.
        base = np.stack([(cell % side + 0.5) / side, (cell // side + 0.5) / side], -1)
        jitter = (rng.random((samples, count, 2)) - 0.5) / side
        offsets = base[:, None, :] + jitter + rng.random((1, count, 2))
        offsets -= np.floor(offsets)   # wrapped into the pixel (np.remainder is slower)
    px = (xs[None, :] + offsets[..., 0]).ravel()
    py = (ys[None, :] + offsets[..., 1]).ravel()
    pixel = np.tile(pixels, samples)
    sample = np.repeat(np.arange(samples), count)
    return px, py, pixel, sample
