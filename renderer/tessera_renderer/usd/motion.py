"""Transform motion over the camera's shutter (the MotionReader part of the translator).

UsdGeomCamera's `shutter:open` and `shutter:close` are offsets from the render's time code,
in time codes (0 and 0, the schema's fallbacks, mean no motion blur). A prim whose world
transform changes inside [frame + open, frame + close] is translated once in its own space
and placed by an instance that moves through T matrices evenly spaced over the shutter
(Embree's motion model: ray time 0 is shutter open, 1 is close; linear in between).

T follows what is authored: enough steps to land on every time sample inside the shutter
when they are evenly spaced, then doubled segment by segment until the linear
interpolation between steps stays within MOTION_TOLERANCE of USD's own transform at each
segment's midpoint (a rotation needs more steps than a slide), at most MAX_TIME_STEPS.

PointInstancers move the same way, per instance (positions, orientations, scales,
velocities, angular velocities and accelerations, through USD's own
ComputeInstanceTransformsAtTimes), and so does the camera (CameraDesc.motion: its poses
at the steps). A mesh whose `points` are time-sampled inside the shutter deforms: its
points at T steps (chosen the same way, on the points) make a deforming prototype (Embree
vertex time steps), placed by a still or moving instance; so does a mesh whose `velocities`
(and `accelerations`) move its points from the points sample at or before the frame, as
USD's ComputePointsAtTimes extrapolates them (per second: timeCodesPerSecond codes). Sphere, point, distant and dome
lights move rigidly (light_motion: their motion relative to the frame, without scale);
rect, disk and cylinder lights are geometry and move like any other prim. Subdivision
surfaces refine each step's cage (stage.py), skinned meshes are posed at each step
(meshes.py, skin). Not blurred yet, each named in one warning: deforming or skinned meshes
inside instance prototypes.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .errors import SceneError, local_to_world, read_float

MAX_TIME_STEPS = 129          # Embree 3's limit on a geometry's time steps
MOTION_TOLERANCE = 1e-4       # of the prim's size: the largest chord error between steps


@dataclass(frozen=True)
class Shutter:
    """The shutter interval in absolute time codes (open < close)."""

    open: float
    close: float

    def times(self, steps: int) -> np.ndarray:
        return np.linspace(self.open, self.close, steps)


def render_time(stage, frame: float | None):
    """The time code a render reads: `frame` when given, else the stage's startTimeCode when
    it authors a time range (usdview opens a stage there), else the default time."""
    from pxr import Usd

    if frame is not None:
        if not math.isfinite(frame):
            raise SceneError(f"frame must be a finite time code, not {frame!r}")
        return Usd.TimeCode(frame)
    if stage.HasAuthoredTimeCodeRange():
        return Usd.TimeCode(stage.GetStartTimeCode())
    return Usd.TimeCode.Default()


def shutter_interval(camera_prim, time, override: tuple[float, float] | None) -> Shutter | None:
    """The shutter around `time`: `override` (open, close offsets) when given, else the
    camera's shutter:open/close. None when open == close or the time is the default time
    (a stage without time samples cannot move)."""
    from pxr import UsdGeom

    if override is not None:
        open_, close = (float(v) for v in override)
        source = "shutter"
    elif camera_prim is not None:
        cam = UsdGeom.Camera(camera_prim)
        open_ = read_float(cam.GetShutterOpenAttr(), time)
        close = read_float(cam.GetShutterCloseAttr(), time)
        source = f"{camera_prim.GetPath()}: shutter:open/close"
    else:
        return None
    if not (math.isfinite(open_) and math.isfinite(close)) or open_ > close:
        raise SceneError(f"{source} ({open_:g}, {close:g}) must be finite with open <= close")
    if open_ == close or time.IsDefault():
        return None
    return Shutter(time.GetValue() + open_, time.GetValue() + close)


class _TopologyChanges(Exception):
    """A deforming mesh's point count differs between two instants of the shutter."""


class MotionReader:
    """World matrices of moving prims at evenly spaced instants of the shutter."""

    def _init_motion(self, shutter: Shutter | None) -> None:
        self.shutter = shutter
        self._varying: dict[str, bool] = {}
        self._caches: dict[float, object] = {}
        # (index of the instance in the concatenated instances, its matrices (T, 4, 4)).
        self.motion: list[tuple[int, np.ndarray]] = []
        # Moving lights: (LightKind number, index among its kind, rigid deltas (T, 4, 4)).
        self.light_motion: list[tuple[int, int, np.ndarray]] = []
        self._counted = (0, 0)  # (arrays of self.instances counted, instances in them)

    def _cache_at(self, t: float):
        from pxr import Usd, UsdGeom

        cache = self._caches.get(t)
        if cache is None:
            cache = self._caches[t] = UsdGeom.XformCache(Usd.TimeCode(t))
        return cache

    def _world_at(self, prim, times) -> np.ndarray:
        return np.array([local_to_world(self._cache_at(float(t)), prim) for t in times])

    def transform_varies(self, prim) -> bool:
        """Whether the prim's or an ancestor's xformOps are time-sampled (memoised)."""
        from pxr import UsdGeom

        path = str(prim.GetPath())
        known = self._varying.get(path)
        if known is not None:
            return known
        xf = UsdGeom.Xformable(prim)
        varies = bool(xf) and xf.TransformMightBeTimeVarying()
        parent = prim.GetParent()
        if not varies and parent and not (bool(xf) and xf.GetResetXformStack()):
            varies = self.transform_varies(parent)
        self._varying[path] = varies
        return varies

    def _key_times(self, prim) -> list[float]:
        """Authored transform samples strictly inside the shutter, of the prim and its
        ancestors."""
        from pxr import Gf, UsdGeom

        keys: set[float] = set()
        interval = Gf.Interval(self.shutter.open, self.shutter.close, False, False)
        p = prim
        while p:
            xf = UsdGeom.Xformable(p)
            if xf:
                for op in xf.GetOrderedXformOps():
                    keys.update(op.GetTimeSamplesInInterval(interval))
                if xf.GetResetXformStack():
                    break
            p = p.GetParent()
        return sorted(keys)

    def motion_steps(self, prim, local_points: np.ndarray, base_inv: np.ndarray | None = None) -> np.ndarray | None:
        """World matrices (T, 4, 4) of `prim` (times base_inv) at T evenly spaced instants of
        the shutter, or None when it does not move during it. local_points bound the
        geometry the matrices move (the tolerance is relative to its size)."""
        if self.shutter is None or not self.transform_varies(prim) or len(local_points) == 0:
            return None

        def world(times):
            m = self._world_at(prim, times)
            return (m @ base_inv if base_inv is not None else m)[:, None]

        mats = self.sample_motion(world, local_points, self._key_times(prim), str(prim.GetPath()))
        return None if mats is None else mats[:, 0]

    def sample_motion(self, world, local_points: np.ndarray, keys: list[float], path: str) -> np.ndarray | None:
        """world(times) -> (T, N, 4, 4) matrices of N placements at those time codes: sampled
        at T evenly spaced instants of the shutter, T chosen as the module says. None when
        no placement moves during the shutter."""
        lo, hi = local_points.min(axis=0), local_points.max(axis=0)
        corners = np.array([[x, y, z, 1.0] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
        mats = self._over_shutter(
            world, keys,
            lambda off: np.abs(np.einsum("cj,snjk->snck", corners, off)[..., :3]).max(),
            lambda mats: max(np.abs(np.einsum("cj,snjk->snck", corners, mats)[..., :3]).max(), 1e-30))
        if not np.isfinite(mats).all():
            raise SceneError(f"{path}: its transform is not finite during the shutter")
        if np.array_equal(mats, np.broadcast_to(mats[:1], mats.shape)):
            return None  # samples outside the shutter only: static while it is open
        return mats

    def _over_shutter(self, sample, keys: list[float], error, size) -> np.ndarray:
        """sample(times) at T evenly spaced instants of the shutter: enough to land on the
        keys when they are evenly spaced, then doubled until error(exact - chord) at every
        segment's midpoint is at most MOTION_TOLERANCE * size(samples), at most MAX_TIME_STEPS."""
        span = self.shutter.close - self.shutter.open
        steps = 2
        if keys:
            gaps = np.diff([self.shutter.open, *keys, self.shutter.close])
            steps = min(MAX_TIME_STEPS, int(math.ceil(span / max(gaps.min(), span * 1e-6) - 1e-9)) + 1)
        while True:
            times = self.shutter.times(steps)
            values = sample(times)
            if steps >= MAX_TIME_STEPS:
                return values
            exact = sample(0.5 * (times[:-1] + times[1:]))
            chord = 0.5 * (values[:-1] + values[1:])
            if not error(exact - chord) > MOTION_TOLERANCE * size(values):  # NaN stops here
                return values
            steps = min(MAX_TIME_STEPS, 2 * steps - 1)

    def deforming_points(self, prim, n_points: int | None = None) -> np.ndarray | None:
        """A mesh's points (T, V, 3) at T evenly spaced instants of the shutter when its
        `points` change during it (USD interpolates them linearly between samples) or its
        velocities move them (moves_by_velocities), else None. Meshes whose point count
        changes inside the shutter, or whose points are not finite there, are left at the
        frame with a note. n_points: the mesh's point count at the frame (None: read it)."""
        from pxr import Gf, UsdGeom

        from .meshes import _float_rows

        based = UsdGeom.PointBased(prim)
        attr = based.GetPointsAttr()
        by_velocity = self.moves_by_velocities(prim)
        if not by_velocity and not self.deforms_during_shutter(attr):
            return None
        if n_points is None:
            n_points = len(attr.Get(self.time) or [])
        interval = Gf.Interval(self.shutter.open, self.shutter.close, False, False)

        def sample(times):
            if by_velocity:
                rows = [_float_rows(p, 3) for p in based.ComputePointsAtTimes([float(t) for t in times], self.time)]
            else:
                rows = [_float_rows(attr.Get(float(t)), 3) for t in times]
            if len(rows) != len(times) or any(r is None or len(r) != n_points for r in rows):
                raise _TopologyChanges
            return np.stack(rows)

        try:
            keys = [] if by_velocity else list(attr.GetTimeSamplesInInterval(interval))
            steps = self._over_shutter(sample, keys,
                                       lambda off: np.abs(off).max(),
                                       lambda pts: max(np.abs(pts).max(), 1e-30))
        except _TopologyChanges:
            self._count_note("meshes whose point count changes during the shutter are not motion-blurred: "
                             "rendered in their shape at the frame")
            return None
        if not np.isfinite(steps).all():
            self.warn(f"{prim.GetPath()}: points are not finite during the shutter; not motion-blurred")
            return None
        return steps

    def add_moving_chunk(self, chunk, mats: np.ndarray, path: str) -> None:
        """A prim's triangles (in its own space, deforming when chunk.motion_points is set)
        as a prototype of its own, placed by one instance moving through `mats` (T, 4, 4),
        or standing still when T is 1."""
        chunks: list = []
        self.emit(chunk, chunks, path)
        if not chunks:
            return
        self.prototypes.append({"chunks": chunks, "triangles": sum(len(c.tris) for c in chunks)})
        self.add_moving_instance(len(self.prototypes) - 1, mats)

    def add_moving_instance(self, proto: int, mats: np.ndarray) -> None:
        self.add_moving_instances(proto, mats[:, None])

    def add_moving_instances(self, proto: int, mats: np.ndarray) -> None:
        """N instances of a prototype, moving through mats (T, N, 4, 4)."""
        # The instances before these, counted incrementally: many moving prims stay linear.
        arrays, index = self._counted
        for a in self.instances[arrays:]:
            index += len(a)
        self._counted = (len(self.instances) + 1, index + mats.shape[1])
        self.instances.append(np.full(mats.shape[1], proto, np.uint32))
        self.instance_xforms.append(mats[0].copy())
        if len(mats) > 1:  # a single step places a still instance (of a deforming prototype)
            self.motion.extend((index + j, mats[:, j]) for j in range(mats.shape[1]))

    def point_instancer_motion(self, prim, pi, world_base: np.ndarray | None) -> "callable | None":
        """For a PointInstancer that moves during the shutter (its own transform, or
        time-sampled positions, orientations, scales, velocities or angular velocities):
        world(times) -> (T, N, 4, 4), every instance's placement at those time codes
        (USD's ComputeInstanceTransformsAtTimes, velocities applied from the render's
        time), and the authored keys inside the shutter. None when nothing can move."""
        from pxr import Gf, Usd, UsdGeom

        if self.shutter is None:
            return None
        attrs = [pi.GetPositionsAttr(), pi.GetOrientationsAttr(), pi.GetScalesAttr(), pi.GetVelocitiesAttr(),
                 pi.GetAngularVelocitiesAttr(), pi.GetAccelerationsAttr()]
        sampled = [a for a in attrs if a and a.GetNumTimeSamples() > 0]
        if not sampled and not self.transform_varies(prim):
            return None
        count = len(pi.GetProtoIndicesAttr().Get(self.time) or [])
        interval = Gf.Interval(self.shutter.open, self.shutter.close, False, False)
        keys = set(self._key_times(prim))
        for a in sampled:
            keys.update(a.GetTimeSamplesInInterval(interval))

        def world(times):
            per_time = pi.ComputeInstanceTransformsAtTimes([Usd.TimeCode(float(t)) for t in times], self.time,
                                                           UsdGeom.PointInstancer.IncludeProtoXform,
                                                           UsdGeom.PointInstancer.IgnoreMask)
            placed = np.asarray(per_time, np.float64).reshape(len(times), -1, 4, 4)
            if placed.shape[1] != count:
                raise SceneError(f"{prim.GetPath()}: {placed.shape[1]} instance transforms during the shutter "
                                 f"for {count} protoIndices (protoIndices must not change inside the shutter)")
            frames = self._world_at(prim, times)
            if world_base is not None:
                frames = frames @ world_base
            return placed @ frames[:, None]

        return world, sorted(keys)

    def camera_poses(self, camera_prim) -> tuple[float, ...] | None:
        """A moving camera's poses (origin, right, up, forward per step, flat) at evenly
        spaced instants of the shutter, or None when it stands still. The steps are chosen
        on a unit box around the camera, relative to where it is at the frame, so the
        tolerance holds for its turn as for its travel however far it is from the origin."""
        here = np.eye(4)
        here[3, :3] = -np.array(self.world_matrix(camera_prim))[3, :3]
        box = np.array([[x, y, z] for x in (-1.0, 1.0) for y in (-1.0, 1.0) for z in (-1.0, 1.0)])
        mats = self.motion_steps(camera_prim, box, base_inv=here)
        if mats is None:
            return None
        poses = []
        for m in mats @ np.linalg.inv(here):
            forward = -m[2, :3] / np.linalg.norm(m[2, :3])
            right = m[0, :3] - np.dot(m[0, :3], forward) * forward
            right /= np.linalg.norm(right)
            poses += [*m[3, :3], *right, *np.cross(right, forward), *forward]
        if not np.isfinite(poses).all():
            raise SceneError(f"{camera_prim.GetPath()}: the camera's transform is degenerate during the shutter")
        return tuple(float(v) for v in poses)

    def moves_during_shutter(self, prim) -> bool:
        """For what is not blurred yet (a warning names it): does the prim move?"""
        if self.shutter is None or not self.transform_varies(prim):
            return False
        mats = self._world_at(prim, self.shutter.times(3))
        return not np.array_equal(mats, np.broadcast_to(mats[:1], mats.shape))

    def moves_by_velocities(self, prim) -> bool:
        """Whether a point-based prim's `velocities` move its points during the shutter. USD
        applies them (with `accelerations`) only to a time-sampled `points`, from its sample
        at or before the frame; velocities on points without samples get a note and are
        left alone, as USD leaves them."""
        from pxr import UsdGeom

        if self.shutter is None:
            return False
        based = UsdGeom.PointBased(prim)
        if not based or not based.GetVelocitiesAttr().HasAuthoredValue():
            return False
        if based.GetPointsAttr().GetNumTimeSamples() == 0:
            self._count_note("mesh velocities on points without time samples are ignored (as USD's "
                             "ComputePointsAtTime ignores them): not motion-blurred")
            return False
        ends = based.ComputePointsAtTimes([self.shutter.open, self.shutter.close], self.time)
        return len(ends) == 2 and not np.array_equal(np.asarray(ends[0]), np.asarray(ends[1]))

    def deforms_during_shutter(self, attr) -> bool:
        """Whether a points-like attribute has time samples that change it in the shutter."""
        from pxr import Gf

        if self.shutter is None or attr.GetNumTimeSamples() < 2:
            return False
        lo, hi = attr.GetBracketingTimeSamples(self.shutter.open)[0], \
            attr.GetBracketingTimeSamples(self.shutter.close)[1]
        if len(attr.GetTimeSamplesInInterval(Gf.Interval(lo, hi))) < 2:
            return False
        first, *rest = (np.asarray(attr.Get(float(t))) for t in self.shutter.times(3))
        return not all(np.array_equal(first, other) for other in rest)

    def light_motion_tables(self):
        """(light_motion_kinds uint8 (K,), light_motion_indices uint32 (K,),
        light_motion_time_steps uint32 (K,), light_motion_transforms float32 (steps, 4, 4))."""
        if not self.light_motion:
            return (np.zeros(0, np.uint8), np.zeros(0, np.uint32), np.zeros(0, np.uint32),
                    np.zeros((0, 4, 4), np.float32))
        return (np.array([k for k, _, _ in self.light_motion], np.uint8),
                np.array([i for _, i, _ in self.light_motion], np.uint32),
                np.array([len(m) for _, _, m in self.light_motion], np.uint32),
                np.concatenate([m for _, _, m in self.light_motion]).astype(np.float32))

    def motion_tables(self):
        """(motion_instances uint32 (K,), motion_time_steps uint32 (K,), motion_transforms
        float32 (sum of steps, 4, 4)) for SceneData."""
        if not self.motion:
            return np.zeros(0, np.uint32), np.zeros(0, np.uint32), np.zeros((0, 4, 4), np.float32)
        return (np.array([i for i, _ in self.motion], np.uint32),
                np.array([len(m) for _, m in self.motion], np.uint32),
                np.concatenate([m for _, m in self.motion]).astype(np.float32))
