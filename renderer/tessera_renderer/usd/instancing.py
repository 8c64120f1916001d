"""Native instances and PointInstancers: prototypes kept once with instance transforms, or
flattened into copies (the InstanceReader part of the translator)."""
from __future__ import annotations

import numpy as np

from .errors import SceneError
from .meshes import _Chunk


class InstanceReader:
    """Turns instanced prims into prototypes + transforms, or flat copies."""

    # -- instancing -----------------------------------------------------------------
    def prototype(self, key: str, prim_range, base_inv) -> int:
        """Index of a prototype, translating it once (geometry in its own space)."""
        if key in self._proto_index:
            return self._proto_index[key]
        chunks: list[_Chunk] = []
        self.walk(prim_range, base_inv, chunks, top_level=False)
        self._proto_index[key] = len(self.prototypes)
        self.prototypes.append({"chunks": chunks, "triangles": sum(len(c.tris) for c in chunks)})
        return self._proto_index[key]

    def native_key(self, prim) -> str:
        """Prototype key of a native instance: its USD prototype and the materials its
        gprims resolve to. Bindings authored on the instance or its ancestors (possibly
        strongerThanDescendants) reach the prototype's prims, so instances of one USD
        prototype bound differently become different prototypes here."""
        from pxr import Usd, UsdGeom, UsdShade

        def material(p) -> str:
            m = UsdShade.MaterialBindingAPI(p).ComputeBoundMaterial()[0]
            if not m:
                return ""
            # A material inside the instance is an instance proxy: name it by its prototype
            # prim, which every instance shares (as material_row's cache does).
            mp = m.GetPrim()
            return str(mp.GetPrimInPrototype().GetPath() if mp.IsInstanceProxy() else mp.GetPath())

        sig = []
        for p in Usd.PrimRange(prim, Usd.TraverseInstanceProxies(Usd.PrimDefaultPredicate)):
            if p.IsA(UsdGeom.Gprim):
                sig.append(material(p))
                for subset in UsdShade.MaterialBindingAPI(p).GetMaterialBindSubsets():
                    sig.append(material(subset.GetPrim()))
            if self.light_links:
                # Instances whose prims light links treat differently: prototypes of their own.
                sig.append(f"link group {self.light_links.group_of(p.GetPath())}")
        return f"native:{prim.GetPrototype().GetPath()}:{'|'.join(sig)}"

    def add_native_instance(self, prim) -> None:
        from pxr import Usd

        # Walked through this instance's proxies (not the bare prototype prims), so that
        # material bindings from outside the prototype resolve as USD resolves them;
        # geometry is still read once per prototype prim (the geometry cache).
        rng = Usd.PrimRange(prim, Usd.TraverseInstanceProxies(Usd.PrimDefaultPredicate))
        self._in_native_prototype = True
        try:
            idx = self.prototype(self.native_key(prim), rng, np.linalg.inv(self.world_matrix(prim)))
        finally:
            self._in_native_prototype = False
        points = [c.points for c in self.prototypes[idx]["chunks"] if len(c.points)]
        mats = self.motion_steps(prim, np.concatenate(points)) if points else None
        if mats is not None:
            self.add_moving_instance(idx, mats)
        else:
            self.instances.append(np.array([idx], np.uint32))
            self.instance_xforms.append(self.world_matrix(prim)[None])
        self.instanced_triangles += self.prototypes[idx]["triangles"]

    def add_point_instancer(self, prim, base_inv, sink, top_level) -> None:
        from pxr import Usd, UsdGeom

        pi = UsdGeom.PointInstancer(prim)
        path = str(prim.GetPath())
        targets = pi.GetPrototypesRel().GetForwardedTargets()
        proto_idx = pi.GetProtoIndicesAttr().Get(self.time)
        if proto_idx is None or len(proto_idx) == 0 or not targets:
            self.warn(f"{path}: PointInstancer has no instances or prototypes; skipped")
            return
        proto_idx = np.asarray(proto_idx, dtype=np.int64)
        if proto_idx.min() < 0 or proto_idx.max() >= len(targets):
            raise SceneError(f"{path}: protoIndices reference prototype {int(proto_idx.max())} "
                             f"but there are {len(targets)} prototypes")
        xforms = pi.ComputeInstanceTransformsAtTime(self.time, self.time, UsdGeom.PointInstancer.IncludeProtoXform,
                                                    UsdGeom.PointInstancer.IgnoreMask)
        if xforms is None or len(xforms) == 0:
            self.warn(f"{path}: positions/orientations/scales do not match protoIndices; skipped")
            return
        xforms = np.asarray(xforms, dtype=np.float64).reshape(-1, 4, 4)
        mask = np.asarray(pi.ComputeMaskAtTime(self.time) or [True] * len(proto_idx), bool)
        if len(xforms) != len(proto_idx):
            raise SceneError(f"{path}: {len(xforms)} instance transforms for {len(proto_idx)} protoIndices")
        world = self.world_matrix(prim)
        if base_inv is not None:
            world = world @ base_inv
        # Moving instances are Embree instances: only top-level instancers in instances
        # mode (flattened copies stand at the frame, said once).
        motion = self.point_instancer_motion(prim, pi, base_inv)
        if motion is not None and not (self.instancing == "instances" and top_level):
            self._count_note("moving PointInstancers that are flattened (instancing='flatten', or inside "
                             "another instance) are not motion-blurred: rendered at the frame")
            motion = None
        for k, target in enumerate(targets):
            sel = (proto_idx == k) & mask
            if not sel.any():
                continue
            proto_prim = self.stage.GetPrimAtPath(target)
            if not proto_prim:
                self.warn(f"{path}: prototype {target} does not exist; skipped")
                continue
            # ComputeInstanceTransformsAtTime includes the prototype root's own transform,
            # so prototype geometry is kept in the root's local frame.
            root_inv = np.linalg.inv(self.world_matrix(proto_prim))
            rng = Usd.PrimRange(proto_prim, Usd.TraverseInstanceProxies(Usd.PrimDefaultPredicate))
            # A prototype that is itself a native instance shares that instance's prototype
            # (its own transform is in the instance transforms): translate it once.
            key = self.native_key(proto_prim) if proto_prim.IsInstance() else str(target)
            idx = self.prototype(key, rng, root_inv)
            mats = xforms[sel] @ world
            n = int(sel.sum())
            points = [c.points for c in self.prototypes[idx]["chunks"] if len(c.points)]
            moving = None
            if motion is not None and points:
                world_fn, keys = motion
                moving = self.sample_motion(lambda times: world_fn(times)[:, sel], np.concatenate(points), keys,
                                            path)
            if moving is not None:
                self.add_moving_instances(idx, moving)
                self.instanced_triangles += n * self.prototypes[idx]["triangles"]
            elif self.instancing == "instances" and top_level:
                self.instances.append(np.full(n, idx, np.uint32))
                self.instance_xforms.append(mats)
                self.instanced_triangles += n * self.prototypes[idx]["triangles"]
            else:
                self.flatten_instances(idx, mats, sink, path)

    def flatten_instances(self, proto: int, mats: np.ndarray, sink: list, path: str) -> None:
        """Copies a prototype once per transform, vectorised over instances."""
        n = len(mats)
        total = n * self.prototypes[proto]["triangles"]
        self.instanced_triangles += total
        for c in self.prototypes[proto]["chunks"]:
            pts = np.einsum("vj,njk->nvk", c.points, mats[:, :3, :3]) + mats[:, None, 3, :3]
            flip = np.linalg.det(mats[:, :3, :3]) < 0
            v = len(c.points)
            tris = (c.tris[None] + (np.arange(n) * v)[:, None, None])
            tris = np.where(flip[:, None, None], tris[:, :, ::-1], tris).reshape(-1, 3)
            normals = None
            if c.normals is not None:
                inv_t = np.linalg.inv(mats[:, :3, :3]).transpose(0, 2, 1)
                normals = np.einsum("tcj,njk->ntck", c.normals, inv_t)
                normals = np.where(flip[:, None, None, None], normals[:, :, ::-1], normals).reshape(-1, 3, 3)
            uvs = None
            if c.uvs is not None:
                uvs = np.broadcast_to(c.uvs, (n,) + c.uvs.shape)
                uvs = np.where(flip[:, None, None, None], uvs[:, :, ::-1], uvs).reshape(-1, 3, 2)
            self.emit(_Chunk(pts.reshape(-1, 3), tris, np.tile(c.material, n), normals, uvs), sink, path)


def _instance_corners(chunks: list, mats: np.ndarray) -> np.ndarray:
    """World bounding-box corners of every instance of a prototype (8 per instance)."""
    lo = np.min([c.points.min(axis=0) for c in chunks if len(c.points)], axis=0)
    hi = np.max([c.points.max(axis=0) for c in chunks if len(c.points)], axis=0)
    box = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
    return (np.einsum("vj,njk->nvk", box, mats[:, :3, :3]) + mats[:, None, 3, :3]).reshape(-1, 3)
