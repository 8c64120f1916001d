"""UsdGeom.Camera and UsdRenderSettings -> the camera and resolution; the framing of a
camera-less stage; the camera-relative shift of the translated scene."""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np

from .errors import SceneError, local_to_world, read_float


@dataclass
class CameraDesc:
    origin: tuple[float, float, float]
    right: tuple[float, float, float]
    up: tuple[float, float, float]
    forward: tuple[float, float, float]
    horizontal_aperture: float   # same unit as focal_length; only ratios matter
    vertical_aperture: float
    focal_length: float
    source: str                  # prim path, or a description of the default camera
    # Thin lens (scene units): radius = focal length / (2 fStop), 0 for a pinhole
    # (fStop 0); the focus plane's distance; primary visibility clipped to [near, far].
    lens_radius: float = 0.0
    focus_distance: float = 1.0
    clip_near: float = 0.0
    clip_far: float = math.inf
    # "perspective" or "orthographic"; the aperture offsets shift the image window (a
    # shift lens), in the apertures' unit.
    projection: str = "perspective"
    horizontal_aperture_offset: float = 0.0
    vertical_aperture_offset: float = 0.0
    # A camera moving during the shutter: T poses evenly spaced over it, 12 floats each
    # (origin, right, up, forward), flat; None when it stands still (usd/motion.py).
    motion: tuple[float, ...] | None = None

    @property
    def orthographic(self) -> bool:
        return self.projection == "orthographic"

    def window(self, width: int, height: int) -> tuple[float, float, float, float]:
        """The image window (half width, half height, centre x, centre y) as UsdGeomCamera
        defines it (GfCamera's frustum): perspective, on the image plane at distance 1,
        aperture / focalLength; orthographic, in scene units, the apertures being tenths of
        a scene unit. Fit to the image's aspect ratio by expanding it about its centre
        (never cropping)."""
        scale = 0.1 if self.orthographic else 1.0 / self.focal_length
        half_w, half_h = self.horizontal_aperture * scale / 2.0, self.vertical_aperture * scale / 2.0
        image_aspect = width / height
        if image_aspect >= half_w / half_h:
            half_w = half_h * image_aspect
        else:
            half_h = half_w / image_aspect
        return half_w, half_h, self.horizontal_aperture_offset * scale, self.vertical_aperture_offset * scale

    def tan_half_angles(self, width: int, height: int) -> tuple[float, float]:
        """tan(fov / 2) both ways for a perspective camera (window())."""
        half_w, half_h, _, _ = self.window(width, height)
        return half_w, half_h


def _find_render_settings(stage, warn):
    from pxr import UsdRender

    settings = UsdRender.Settings.GetStageRenderSettings(stage)
    if settings:
        return settings
    candidates = [p for p in stage.Traverse() if p.IsA(UsdRender.Settings)]
    if len(candidates) == 1:
        return UsdRender.Settings(candidates[0])
    if len(candidates) > 1:
        warn(f"{len(candidates)} RenderSettings prims and no renderSettingsPrimPath; using none of them")
    return None


def _camera_from_prim(prim, xform_cache, time, warn) -> CameraDesc:
    from pxr import UsdGeom

    cam = UsdGeom.Camera(prim)
    def authored(attr, fallback):  # an authored 0 is an error below, not the fallback
        return read_float(attr, time, fallback)
    focal = authored(cam.GetFocalLengthAttr(), 50.0)
    hap = authored(cam.GetHorizontalApertureAttr(), 20.955)
    vap = authored(cam.GetVerticalApertureAttr(), 15.2908)
    h_off = authored(cam.GetHorizontalApertureOffsetAttr(), 0.0)
    v_off = authored(cam.GetVerticalApertureOffsetAttr(), 0.0)
    path = str(prim.GetPath())
    orthographic = cam.GetProjectionAttr().Get(time) == UsdGeom.Tokens.orthographic
    if not all(math.isfinite(v) and v > 0 for v in (hap, vap)) or not (orthographic or (math.isfinite(focal) and focal > 0)):
        raise SceneError(f"{path}: focalLength and apertures must be positive "
                         f"(got {focal}, {hap}, {vap})")
    if not (math.isfinite(h_off) and math.isfinite(v_off)):
        raise SceneError(f"{path}: aperture offsets must be finite (got {h_off}, {v_off})")
    # The core takes the window's half extent (perspective: aperture / (2 focalLength);
    # orthographic: 0.05 aperture) as a float32: it must be neither 0 nor infinite there
    # (e.g. focalLength 1e-45 passes the check above).
    scale = 0.1 if orthographic else 1.0 / focal
    if not all(1e-30 < ap * scale / 2.0 < 1e30 for ap in (hap, vap)):
        raise SceneError(f"{path}: the field of view is degenerate (apertures {hap}, {vap}"
                         + ("" if orthographic else f" over focalLength {focal}") + ")")
    m = local_to_world(xform_cache, prim)
    origin = m[3, :3]
    forward = _unit(-m[2, :3])
    right = _unit(m[0, :3] - np.dot(m[0, :3], forward) * forward)
    up = np.cross(right, forward)
    if not np.isfinite(np.concatenate([origin, forward, right, up])).all():
        raise SceneError(f"{path}: camera transform is degenerate")
    # Depth of field: focalLength is in tenths of a scene unit, fStop 0 means a pinhole.
    f_stop = read_float(cam.GetFStopAttr(), time)
    focus = read_float(cam.GetFocusDistanceAttr(), time)
    lens_radius = 0.0
    if f_stop > 0.0 and math.isfinite(f_stop) and orthographic:
        warn(f"{path}: fStop {f_stop:g} on an orthographic camera; rendered without depth of field")
    elif f_stop > 0.0 and math.isfinite(f_stop):
        if focus > 0.0 and math.isfinite(focus):
            lens_radius = 0.1 * focal / (2.0 * f_stop)
            if not lens_radius < 1e30:  # the core holds it as a float32
                raise SceneError(f"{path}: fStop {f_stop:g} makes the lens infinitely wide "
                                 f"(its radius is focalLength / (2 fStop))")
        else:
            warn(f"{path}: fStop {f_stop:g} without a positive focusDistance; rendered without depth of field")
    # Only an authored clipping range clips: the schema's fallback (1, 1e6) would cut away
    # whatever lies within one unit of the camera in scenes that never asked for it.
    clip_attr = cam.GetClippingRangeAttr()
    clip = clip_attr.Get(time) if clip_attr.HasAuthoredValue() else None
    near, far = (float(clip[0]), float(clip[1])) if clip is not None else (0.0, math.inf)
    if not (0.0 <= near < far):
        warn(f"{path}: clippingRange {tuple(clip)} is invalid; not clipping")
        near, far = 0.0, math.inf
    return CameraDesc(_floats(origin), _floats(right), _floats(up), _floats(forward), hap, vap, focal, path,
                      lens_radius=lens_radius, focus_distance=focus if lens_radius > 0 else 1.0,
                      clip_near=near, clip_far=far,
                      projection="orthographic" if orthographic else "perspective",
                      horizontal_aperture_offset=h_off, vertical_aperture_offset=v_off)


# In the warning select_camera gives when it picks the first of several cameras.
CAMERA_CHOICE_NOTE = "cameras and no RenderSettings camera; using"


def camera_paths(stage) -> list[str]:
    """The paths of the stage's Camera prims (instance proxies included), in traversal order."""
    from pxr import Usd, UsdGeom

    return [str(p.GetPath()) for p in Usd.PrimRange.Stage(stage, Usd.TraverseInstanceProxies(Usd.PrimDefaultPredicate))
            if p.IsA(UsdGeom.Camera)]


def select_camera(stage, requested: str | None, settings, cameras: list, warn):
    """The camera prim to render through: `requested` (a prim path: `--camera`, the job's
    `camera`), else the RenderSettings' camera, else the only/first camera found, else
    None (the default camera). A requested path that is not a Camera is a SceneError that
    lists the stage's cameras."""
    from pxr import Sdf, UsdGeom

    if requested is not None:
        found = ", ".join(str(c.GetPath()) for c in cameras) or "none"
        if not Sdf.Path.IsValidPathString(requested) or not Sdf.Path(requested).IsAbsolutePath():
            raise SceneError(f"camera {requested!r} is not an absolute prim path (the stage's cameras: {found})")
        prim = stage.GetPrimAtPath(requested)
        if not prim or not prim.IsA(UsdGeom.Camera):
            what = "is not a Camera prim" if prim else "does not exist"
            raise SceneError(f"camera {requested} {what} (the stage's cameras: {found})")
        return prim
    if settings:
        targets = settings.GetCameraRel().GetForwardedTargets()
        if targets:
            prim = stage.GetPrimAtPath(targets[0])
            if not prim or not prim.IsA(UsdGeom.Camera):
                raise SceneError(f"{settings.GetPath()}: camera {targets[0]} is not a Camera prim")
            return prim
    if cameras:
        if len(cameras) > 1:
            warn(f"{len(cameras)} {CAMERA_CHOICE_NOTE} {cameras[0].GetPath()} (--camera picks another)")
        return cameras[0]
    return None


# The default camera's view: a three-quarter view from the front-right, above (degrees),
# and the share of the frame the scene's extent may fill in its limiting direction.
DEFAULT_VIEW_AZIMUTH = 45.0
DEFAULT_VIEW_ELEVATION = 30.0
DEFAULT_VIEW_FILL = 0.95


def _default_camera(points: np.ndarray, up_axis: str, resolution: tuple[int, int]) -> CameraDesc:
    """Frames `points` (world space) tightly from a three-quarter view, as usdview's "frame
    all" fits the scene to its view: looking at the centre of their bounds from
    DEFAULT_VIEW_AZIMUTH degrees right of the front (+Z on Y-up stages, -Y on Z-up) and
    DEFAULT_VIEW_ELEVATION above, at the distance where every point projects inside
    DEFAULT_VIEW_FILL of the frame, re-aimed once so the projected extent is centred. A
    50 mm lens with a 24 mm vertical aperture, the horizontal one matching the
    resolution's aspect ratio (so the fit holds for the image rendered)."""
    pts = points if len(points) else np.zeros((1, 3))
    if up_axis == "Z":
        front, up_w = np.array([0.0, -1.0, 0.0]), np.array([0.0, 0.0, 1.0])
    else:
        front, up_w = np.array([0.0, 0.0, 1.0]), np.array([0.0, 1.0, 0.0])
    right_w = np.cross(up_w, front)  # +X on both
    az, el = math.radians(DEFAULT_VIEW_AZIMUTH), math.radians(DEFAULT_VIEW_ELEVATION)
    eye_dir = math.cos(el) * (math.cos(az) * front + math.sin(az) * right_w) + math.sin(el) * up_w
    forward = -eye_dir
    right = _unit(np.cross(forward, up_w))
    up = np.cross(right, forward)
    aspect = resolution[0] / resolution[1]
    vap, focal = 24.0, 50.0
    hap = vap * aspect
    tan_w, tan_h = hap / (2 * focal) * DEFAULT_VIEW_FILL, vap / (2 * focal) * DEFAULT_VIEW_FILL
    lo, hi = pts.min(axis=0), pts.max(axis=0)
    target = (lo + hi) / 2
    size = max(float(np.linalg.norm(hi - lo)), 1e-3)
    q = pts - target
    x, y, z = q @ right, q @ up, q @ forward

    def distance(sx, sy):  # camera distance fitting every point, target shifted by (sx, sy)
        return float(max(np.max(np.abs(x - sx) / tan_w - z), np.max(np.abs(y - sy) / tan_h - z)))

    sx = sy = 0.0
    d = distance(sx, sy)
    depth = np.maximum(d + z, 1e-9)
    u, v = (x - sx) / depth, (y - sy) / depth
    # Centre the projected extent: shift the aim by the middle of the extent at the
    # target's depth, then fit again.
    sx += (u.max() + u.min()) / 2 * d
    sy += (v.max() + v.min()) / 2 * d
    d = max(distance(sx, sy), size * 1e-3)
    origin = target + sx * right + sy * up - forward * d
    return CameraDesc(_floats(origin), _floats(right), _floats(up), _floats(forward), hap, vap, focal,
                      "default camera: three-quarter view framing the scene")


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v)


def _move_to_camera(tr, camera: CameraDesc) -> CameraDesc:
    """Translates everything the walk put in world space so that the camera sits at the
    origin, in float64 before anything is rounded to float32. float32 holds a coordinate
    to 2^-24 of its magnitude: 1e5 units from the origin that is 0.006, more than a pixel's
    footprint on a subject a few units from the camera. Relative to the camera, a point at
    distance D is held to D 2^-24, far below the pixel footprint at D (D 2 tan(fov/2) / width)
    at any resolution, and rays leave surfaces by about D 1e-6 (the hit points' error
    bounds), so only gaps thinner than that, at that distance, can leak light."""
    shift = np.array(camera.origin, np.float64)
    if not shift.any():
        return camera
    for c in tr.chunks:
        c.points = c.points - shift
    for pts in tr.curves["points"]:
        pts[:, :3] -= shift
    for row in tr.sphere_lights:
        row[:3] = list(np.asarray(row[:3], np.float64) - shift)
    for row in tr.point_lights:
        row[:3] = list(np.asarray(row[:3], np.float64) - shift)
    for rows in tr.light_rows.values():  # a row's first three columns are a position
        for row in rows:
            row[:3] = list(np.asarray(row[:3], np.float64) - shift)
    for mats in tr.instance_xforms:
        mats[:, 3, :3] -= shift
    for _, mats in tr.motion:
        mats[:, 3, :3] -= shift
    for _, _, deltas in tr.light_motion:  # p(t) = p(frame) @ delta, in world coordinates
        deltas[:, 3, :3] += shift @ deltas[:, :3, :3] - shift
    if camera.motion is not None:
        poses = np.array(camera.motion, np.float64).reshape(-1, 12)
        poses[:, :3] -= shift
        return dataclasses.replace(camera, motion=tuple(float(v) for v in poses.ravel()))
    return camera


def _floats(v) -> tuple[float, float, float]:
    return tuple(float(x) for x in v)
