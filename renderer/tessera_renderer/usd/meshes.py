"""Meshes, gprims and curves -> triangle chunks: topology, triangulation, primvar
expansion, normals, subdivision and UsdSkel posing (the MeshReader part of the
translator)."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from . import curves, gprims, subdivision
from .errors import SceneError, read_float


# UV sets read when no UsdPrimvarReader_float2 names one: the common names of DCC exporters
# (USD's st, Blender's UVMap, Maya's map1, ...), first found wins.
DEFAULT_UV_SETS = ("st", "st0", "UVMap", "uv", "map1")


@dataclass
class _Chunk:
    """Triangles of one prim in some space: points (V,3) f64, tris (T,3) int, per-triangle
    material rows, optional per-corner normals (T,3,3) and st (T,3,2). A deforming prim's
    chunk also holds its points at the shutter's time steps, motion_points (S,V,3); it is
    only ever a prototype's, in the prim's own space."""

    points: np.ndarray
    tris: np.ndarray
    material: np.ndarray
    normals: np.ndarray | None = None
    uvs: np.ndarray | None = None
    motion_points: np.ndarray | None = None

    def transformed(self, m: np.ndarray) -> "_Chunk":
        """The chunk in another space. Normals are left unnormalised (emit normalises)."""
        linear = m[:3, :3]
        identity = np.array_equal(linear, np.eye(3))
        pts = self.points if identity else self.points @ linear
        if m[3, :3].any():
            pts = pts + m[3, :3]
        tris, normals, uvs = self.tris, self.normals, self.uvs
        if normals is not None and not identity:
            # Normals transform by the inverse transpose; row vectors: n @ inv(M3).T
            det = np.linalg.det(linear)
            nm = np.linalg.inv(linear).T if abs(det) > 1e-300 else linear
            normals = normals @ nm.astype(normals.dtype)
        if np.linalg.det(linear) < 0:  # a mirroring transform flips the winding
            tris = tris[:, ::-1]
            normals = normals[:, ::-1] if normals is not None else None
            uvs = uvs[:, ::-1] if uvs is not None else None
        return _Chunk(pts, tris, self.material, normals, uvs)


class MeshReader:
    """Reads geometric prims into _Chunk triangles."""

    # -- skinning -------------------------------------------------------------------
    def skin(self) -> None:
        """Poses every skinned mesh at the render frame, as UsdSkel.BakeSkinning would: the
        skeleton's animation (SkelAnimation, else its rest pose) gives the skinning
        transforms, UsdSkel's skinning query applies them with each mesh's joint
        influences and geomBindTransform (linear blend or dual quaternion, as authored;
        rigid bindings as one transform). The posed points are in the skeleton's space.
        With a shutter, a mesh whose pose changes inside it is posed at time steps too
        (self.skinned_steps; chosen as usd/motion.py chooses a deforming mesh's, landing on
        the animation's keys), and deforms like a mesh with time-sampled points."""
        from pxr import Gf, Usd, UsdSkel

        predicate = Usd.TraverseInstanceProxies(Usd.PrimDefaultPredicate)
        roots = [p for p in Usd.PrimRange.Stage(self.stage, predicate) if p.IsA(UsdSkel.Root)]
        if not roots:
            return
        cache = UsdSkel.Cache()
        for root_prim in roots:
            root = UsdSkel.Root(root_prim)
            cache.Populate(root, predicate)
            for binding in cache.ComputeSkelBindings(root, predicate):
                skel_query = cache.GetSkelQuery(binding.GetSkeleton())
                skel_world = self.world_matrix(skel_query.GetPrim())
                anim = skel_query.GetAnimQuery()
                keys = list(anim.GetJointTransformTimeSamplesInInterval(
                    Gf.Interval(self.shutter.open, self.shutter.close, False, False))) \
                    if self.shutter is not None and anim else []
                for query in binding.GetSkinningTargets():
                    path = str(query.GetPrim().GetPath())
                    if query.HasBlendShapes():
                        self._count_note("UsdSkel blend shapes are not applied (skinning is)")
                    posed = _posed_points(skel_query, query, self.time)
                    if posed is None:
                        self.warn(f"{path}: UsdSkel could not skin this mesh; rendered in its rest pose")
                        continue
                    self.skinned[path] = (posed, skel_world)
                    self.skinned_skeletons[path] = skel_query.GetPrim()
                    if self.shutter is not None:
                        steps = self._skinned_over_shutter(skel_query, query, keys, len(posed))
                        if steps is not None:
                            self.skinned_steps[path] = steps
        if self.skinned:
            blurred = f", {len(self.skinned_steps)} of them motion-blurred" if self.skinned_steps else ""
            self._count_note(f"UsdSkel: {len(self.skinned)} skinned mesh(es) posed at the render frame{blurred}")

    def _skinned_over_shutter(self, skel_query, query, keys: list, n_points: int) -> np.ndarray | None:
        """A skinned mesh's posed points (T, V, 3) at the shutter's time steps when its pose
        changes inside the shutter, else None."""
        def sample(times):
            rows = [_posed_points(skel_query, query, float(t)) for t in times]
            if any(r is None or len(r) != n_points for r in rows):
                raise ValueError("the pose cannot be computed at every instant")
            return np.stack(rows)

        try:
            steps = self._over_shutter(sample, keys, lambda off: np.abs(off).max(),
                                       lambda pts: max(np.abs(pts).max(), 1e-30))
        except ValueError:
            self._count_note("skinned meshes UsdSkel cannot pose at every instant of the shutter are not "
                             "motion-blurred: rendered at the frame")
            return None
        if not np.isfinite(steps).all() or np.array_equal(steps, np.broadcast_to(steps[:1], steps.shape)):
            return None
        return steps

    # -- meshes ---------------------------------------------------------------------
    def mesh_chunk(self, prim) -> _Chunk | None:
        from pxr import UsdGeom, UsdShade

        # Instance proxies of one prototype prim share its geometry: read it once; only
        # the material binding can differ per instance (skinned meshes are posed per prim).
        key = str(prim.GetPrimInPrototype().GetPath()) \
            if prim.IsInstanceProxy() and str(prim.GetPath()) not in self.skinned else None
        if key is not None and key in self._geometry_cache:
            geo = self._geometry_cache[key]
        else:
            geo = self._mesh_geometry(prim)
            if key is not None:
                self._geometry_cache[key] = geo
        if geo is None:
            return None
        points, tris, face_of_tri, normals, uv_set, n_faces = geo
        mesh = UsdGeom.Mesh(prim)
        t = self.time
        materials = np.zeros(len(tris), dtype=np.uint32)
        double_sided = bool(mesh.GetDoubleSidedAttr().Get(t))
        base_row = self.material_row(prim, prim, double_sided)
        materials[:] = base_row
        subsets = UsdShade.MaterialBindingAPI(prim).GetMaterialBindSubsets()
        if subsets:
            face_row = np.full(n_faces, base_row, dtype=np.uint32)
            for subset in subsets:
                idx = subset.GetIndicesAttr().Get(t)
                if idx is None or len(idx) == 0:
                    continue
                idx = np.asarray(idx, dtype=np.int64)
                idx = idx[(idx >= 0) & (idx < n_faces)]
                face_row[idx] = self.material_row(subset.GetPrim(), prim, double_sided)
            materials = face_row[face_of_tri]

        return _Chunk(points, tris, materials, normals, self._uvs_by_material(prim, materials, uv_set))

    def _uvs_by_material(self, prim, materials, uv_set):
        """Per-corner st of each triangle from the UV set its material's textures name
        (UsdPrimvarReader_float2 varname), so subsets bound to materials reading different
        sets each get theirs; the mesh's default set (DEFAULT_UV_SETS) where a material
        names none or names one the mesh lacks (with a warning)."""
        rows = np.unique(materials)
        wanted = {int(r): self._uv_set_of_row(int(r)) for r in rows}
        names = set(wanted.values())
        if names <= {None}:
            return uv_set(None)
        uvs = None
        for name in names:
            values = uv_set(name)
            if values is None and name is not None:
                fallback = uv_set(None)
                self._count_note(f"meshes lack the UV set {name!r} that their material's textures read "
                                 f"(UsdPrimvarReader_float2 varname); "
                                 + ("the mesh's default set is used" if fallback is not None
                                    else "those textures are sampled at st = (0, 0)"))
                values = fallback
            if values is None:
                continue
            if uvs is None:
                uvs = np.zeros((len(materials), 3, 2), np.float32)
            sel = np.isin(materials, [r for r, n in wanted.items() if n == name])
            uvs[sel] = values[sel]
        return uvs

    def _uv_set_of_row(self, row: int) -> str | None:
        """The UV set a material row's textures read (None: no reader, the default set).
        One set per material: textures reading several get the first, with a warning."""
        textures = self.materials.rows[row]["textures"]
        names = [self.materials.textures[t].get("st_primvar") for _, t in sorted(textures.items())]
        names = list(dict.fromkeys(n for n in names if n))
        if len(names) > 1:
            self._count_note(f"materials whose textures read several UV sets ({', '.join(names)}) are "
                             f"rendered with the first for all of them")
        return names[0] if names else None

    def _mesh_geometry(self, prim):
        from pxr import UsdGeom

        mesh = UsdGeom.Mesh(prim)
        path = str(prim.GetPath())
        t = self.time
        points = mesh.GetPointsAttr().Get(t)
        skinned = self.skinned.get(path)
        if skinned is not None:
            points = skinned[0]
        counts = mesh.GetFaceVertexCountsAttr().Get(t)
        face_indices = mesh.GetFaceVertexIndicesAttr().Get(t)
        if points is None or counts is None or face_indices is None:
            self.warn(f"{path}: mesh has no points or faces; skipped")
            return None
        points, counts, face_indices = _float_rows(points, 3), _ints(counts), _ints(face_indices)
        if points is None or counts is None or face_indices is None:
            self.warn(f"{path}: points, faceVertexCounts or faceVertexIndices have the wrong type; skipped")
            return None
        if len(points) == 0 or len(counts) == 0:
            self.warn(f"{path}: mesh has no points or faces; skipped")
            return None
        if np.any(counts < 0):
            raise SceneError(f"{path}: faceVertexCounts has {int(np.count_nonzero(counts < 0))} negative "
                             f"entries (the first, {int(counts[counts < 0][0])}, at face {int(np.argmax(counts < 0))})")
        if counts.sum() != len(face_indices):
            raise SceneError(f"{path}: faceVertexCounts sum to {int(counts.sum())} but there are "
                             f"{len(face_indices)} faceVertexIndices")
        if len(face_indices) and (face_indices.min() < 0 or face_indices.max() >= len(points)):
            raise SceneError(f"{path}: faceVertexIndices reference vertex "
                             f"{int(face_indices.max() if face_indices.max() >= len(points) else face_indices.min())}"
                             f" but the mesh has {len(points)} points")
        if np.any(counts < 3):
            self.warn(f"{path}: {int(np.count_nonzero(counts < 3))} faces with fewer than 3 vertices skipped")

        corners, face_of_tri = _triangulate_corners(counts)
        _split_concave_quads(corners, counts, face_indices, points)
        holes = mesh.GetHoleIndicesAttr().Get(t)
        h = np.zeros(0, dtype=np.int64)
        if holes is not None and len(holes):
            hole = np.zeros(len(counts), bool)
            h = np.asarray(holes, dtype=np.int64)
            h = h[(h >= 0) & (h < len(counts))]
            hole[h] = True
            keep = ~hole[face_of_tri]
            corners, face_of_tri = corners[keep], face_of_tri[keep]
        tris = face_indices[corners]
        left = mesh.GetOrientationAttr().Get(t) == UsdGeom.Tokens.leftHanded
        if left:
            corners, tris = corners[:, ::-1], tris[:, ::-1]
        scheme = mesh.GetSubdivisionSchemeAttr().Get(t)
        if len(tris) == 0:
            return None
        api = UsdGeom.PrimvarsAPI(prim)
        shape = (len(points), len(counts), len(face_indices))
        if scheme not in (None, UsdGeom.Tokens.none):
            if self.subdivision_level == 0:
                self._count_note(f"subdivision surfaces ({scheme}) are rendered as their flat control "
                                 f"cage with smooth vertex normals (subdivision level 0)")
            else:
                refined = subdivision.refine(mesh, t, points, counts, face_indices, left,
                                             self._subdivision_level(counts, str(scheme), path), h,
                                             self._count_note)
                if refined is not None:
                    self.subdivided_meshes += 1
                    self.subdivision_limits[path] = refined.limit_points
                    return self._refined_geometry(refined, api, shape, counts, face_indices, path)

        normals = None
        pv = api.GetPrimvar("normals")
        if pv and pv.HasAuthoredValue():
            normals = self.corner_primvar(pv, corners, tris, face_of_tri, shape, 3, path)
        if normals is None:
            raw = mesh.GetNormalsAttr().Get(t)
            raw = _float_rows32(raw, 3) if raw is not None else None
            if raw is None and mesh.GetNormalsAttr().HasAuthoredValue():
                self.warn(f"{path}: normals have the wrong type; ignored")
            if raw is not None and len(raw):
                interp = mesh.GetNormalsInterpolation()
                normals = _expand(raw, interp, None,
                                  corners, tris, face_of_tri, shape)
                if normals is None:
                    self.warn(f"{path}: normals have {len(raw)} values, wrong for {interp}; ignored")
        if normals is not None and skinned is not None:
            # Authored normals are the rest pose's: shade the posed surface smoothly.
            self._count_note("skinned meshes get smooth normals of the posed surface (their authored "
                             "normals are the rest pose's)")
            normals = _vertex_normals(points, tris)
        if normals is None and scheme not in (None, UsdGeom.Tokens.none):
            normals = _vertex_normals(points, tris)  # smooth look for the unsubdivided cage
        sets: dict = {}

        def uv_set(name: str | None):
            """Per-corner values of a named UV set, or of the default set for None;
            None when the mesh has no such primvar. Read once per name."""
            if name not in sets:
                if name is None:
                    found = [n for n in DEFAULT_UV_SETS if api.HasPrimvar(n)]
                    pv = api.GetPrimvar(found[0]) if found else None
                else:
                    pv = api.GetPrimvar(name) if api.HasPrimvar(name) else None
                sets[name] = self.corner_primvar(pv, corners, tris, face_of_tri, shape, 2, path) \
                    if pv is not None else None
            return sets[name]

        return points, tris, face_of_tri, normals, uv_set, len(counts)

    def _subdivision_level(self, counts, scheme: str, path: str) -> int:
        """The job's refinement level (or the dicing pass's for this mesh), lowered for a
        mesh whose refined triangles would pass its share of the triangle limit (with a note)."""
        n_quads = int(counts.sum()) if scheme != "loop" else 0  # an n-gon makes n quads
        n_tris = len(counts)
        budget = self.limits.triangles // subdivision.MESH_SHARE_OF_TRIANGLE_LIMIT
        wanted = self.subdivision_level
        if self.dicing_plan is not None:
            # Meshes the dicing pass did not meet (none expected) keep the fixed level.
            wanted = self.dicing_plan.get(path, wanted)
        elif self.dicing_without_camera:
            self._count_note(f"subdivision meshes refined at the fixed level {wanted}: dicing needs the "
                             f"stage's camera")
        level = wanted
        while level > 1 and subdivision.refined_triangles(n_quads, n_tris, scheme, level) > budget:
            level -= 1
        if level < wanted:
            self._count_note(f"subdivision meshes refined to level {level} instead of "
                             f"{wanted} to stay within {budget} triangles each")
        self.subdivision_levels[level] += 1
        return level

    def _refined_geometry(self, refined, api, shape, counts, face_indices, path):
        """_mesh_geometry's answer for a subdivided mesh: limit surface and limit normals
        (authored normals do not apply to subdivision surfaces, as the schema says); UV
        sets refined from their per-corner cage values."""
        n_corners = len(face_indices)
        cage_corners = np.arange(n_corners, dtype=np.int64)[:, None]
        corner_face = np.repeat(np.arange(len(counts), dtype=np.int64), counts)
        cage_tris = face_indices[cage_corners]
        sets: dict = {}

        def uv_set(name: str | None):
            if name not in sets:
                if name is None:
                    found = [n for n in DEFAULT_UV_SETS if api.HasPrimvar(n)]
                    pv = api.GetPrimvar(found[0]) if found else None
                else:
                    pv = api.GetPrimvar(name) if api.HasPrimvar(name) else None
                values = self.corner_primvar(pv, cage_corners, cage_tris, corner_face, shape, 2, path) \
                    if pv is not None else None
                sets[name] = refined.face_varying(values[:, 0]) if values is not None else None
            return sets[name]

        return refined.points, refined.tris, refined.face_of_tri, refined.normals, uv_set, len(counts)

    def corner_primvar(self, pv, corners, tris, face_of_tri, shape, width, path):
        """A primvar of any interpolation, indexed or not, expanded to (T, 3, width)."""
        values = pv.Get(self.time)
        if values is None or len(values) == 0:
            return None
        values = _float_rows32(values, None)
        if values is None or values.shape[1] < width:
            self.warn(f"{path}: primvar {pv.GetPrimvarName()} has the wrong type; ignored")
            return None
        values = values[:, :width]
        indices = pv.GetIndices(self.time) if pv.IsIndexed() else None
        if indices is not None:
            indices = np.asarray(indices, dtype=np.int64)
            if len(indices) and (indices.min() < 0 or indices.max() >= len(values)):
                self.warn(f"{path}: {pv.GetPrimvarName()} indices out of range; primvar ignored")
                return None
        interp = pv.GetInterpolation()
        out = _expand(values, interp, indices, corners, tris, face_of_tri, shape)
        if out is None:
            self.warn(f"{path}: primvar {pv.GetPrimvarName()} has {len(values if indices is None else indices)} "
                      f"values, wrong for {interp} interpolation; ignored")
        return out

    def gprim_chunk(self, prim, type_name) -> _Chunk | None:
        from pxr import UsdGeom

        t = self.time
        g = getattr(UsdGeom, type_name)(prim)
        axis = g.GetAxisAttr().Get(t) if hasattr(g, "GetAxisAttr") else "Z"
        if type_name == "Sphere":
            pts, tris, nrm = gprims.sphere(read_float(g.GetRadiusAttr(), t))
        elif type_name == "Cube":
            pts, tris, nrm = gprims.cube(read_float(g.GetSizeAttr(), t))
        elif type_name == "Cylinder":
            pts, tris, nrm = gprims.cylinder(read_float(g.GetRadiusAttr(), t), read_float(g.GetHeightAttr(), t), axis)
        elif type_name == "Cone":
            pts, tris, nrm = gprims.cone(read_float(g.GetRadiusAttr(), t), read_float(g.GetHeightAttr(), t), axis)
        elif type_name == "Capsule":
            pts, tris, nrm = gprims.capsule(read_float(g.GetRadiusAttr(), t), read_float(g.GetHeightAttr(), t), axis)
        else:
            pts, tris, nrm = gprims.plane(read_float(g.GetWidthAttr(), t), read_float(g.GetLengthAttr(), t), axis)
        if not np.isfinite(pts).all():
            self.warn(f"{prim.GetPath()}: non-finite {type_name} size; skipped")
            return None
        double_sided = bool(g.GetDoubleSidedAttr().Get(t))
        row = self.material_row(prim, prim, double_sided)
        normals = nrm[tris] if type_name != "Cube" else None
        return _Chunk(pts, tris, np.full(len(tris), row, np.uint32), normals, None)

    def nurbs_chunk(self, prim) -> _Chunk | None:
        """A NurbsPatch's surface tessellated (gprims.nurbs_patch), with its (u, v) as st,
        and its trim curves cut out (gprims.trim_loops: the triangles whose centroid lies
        inside an odd number of loops are kept)."""
        from pxr import UsdGeom

        t = self.time
        g = UsdGeom.NurbsPatch(prim)

        def get(attr, default=None):
            value = attr.Get(t)
            return default if value is None else value
        loops = None
        if len(get(g.GetTrimCurveCountsAttr(), [])):
            try:
                loops = gprims.trim_loops(get(g.GetTrimCurveCountsAttr()), get(g.GetTrimCurveOrdersAttr(), []),
                                          get(g.GetTrimCurveVertexCountsAttr(), []),
                                          get(g.GetTrimCurveKnotsAttr(), []), get(g.GetTrimCurveRangesAttr(), []),
                                          get(g.GetTrimCurvePointsAttr(), []))
            except (ValueError, TypeError) as exc:
                self.warn(f"{prim.GetPath()}: NurbsPatch trim curves ignored (the untrimmed surface is rendered): "
                          f"{exc}")
        try:
            u_range, v_range = get(g.GetURangeAttr()), get(g.GetVRangeAttr())
            pts, tris, nrm, uv = gprims.nurbs_patch(
                int(get(g.GetUVertexCountAttr(), 0)), int(get(g.GetVVertexCountAttr(), 0)),
                int(get(g.GetUOrderAttr(), 0)), int(get(g.GetVOrderAttr(), 0)),
                np.asarray(get(g.GetUKnotsAttr(), [])), np.asarray(get(g.GetVKnotsAttr(), [])),
                np.asarray(get(g.GetPointsAttr(), [])), np.asarray(get(g.GetPointWeightsAttr(), [])),
                None if u_range is None else tuple(u_range), None if v_range is None else tuple(v_range),
                min_pieces=gprims.TRIM_GRID_PIECES if loops is not None else 0)
        except (ValueError, TypeError) as exc:
            self.warn(f"{prim.GetPath()}: NurbsPatch skipped: {exc}")
            return None
        if not np.isfinite(pts).all():
            self.warn(f"{prim.GetPath()}: NurbsPatch with non-finite points skipped")
            return None
        if loops is not None:
            tris = tris[gprims.inside_trim(uv[tris].mean(axis=1), loops)]
            if len(tris) == 0:
                self.warn(f"{prim.GetPath()}: its trim curves cut the whole NurbsPatch away")
                return None
        if g.GetOrientationAttr().Get(t) == UsdGeom.Tokens.leftHanded:
            tris = tris[:, ::-1]
            nrm = None if nrm is None else -nrm
        row = self.material_row(prim, prim, bool(g.GetDoubleSidedAttr().Get(t)))
        return _Chunk(pts, tris, np.full(len(tris), row, np.uint32), None if nrm is None else nrm[tris],
                      uv[tris].astype(np.float32))

    def points_chunk(self, prim) -> _Chunk | None:
        """A Points prim as spheres of its widths (gprims.point_spheres); a point without
        an authored width is 1 across, as Hydra draws it."""
        from pxr import UsdGeom

        t = self.time
        g = UsdGeom.Points(prim)
        positions = g.GetPointsAttr().Get(t)
        if positions is None or len(positions) == 0:
            return None
        positions = np.asarray(positions, np.float64)
        widths = g.GetWidthsAttr().Get(t)
        widths = np.ones(1) if widths is None or len(widths) == 0 else np.asarray(widths, np.float64)
        if len(widths) not in (1, len(positions)):
            self.warn(f"{prim.GetPath()}: {len(widths)} widths for {len(positions)} points; "
                      f"the first is used for all")
            widths = widths[:1]
        keep = np.isfinite(positions).all(axis=1) & np.isfinite(np.broadcast_to(widths, (len(positions),))) & \
            (np.broadcast_to(widths, (len(positions),)) > 0)
        if not keep.all():
            self.warn(f"{prim.GetPath()}: {int((~keep).sum())} points with a NaN/Inf position or a width "
                      f"that is not positive skipped")
            widths = widths if len(widths) == 1 else widths[keep]
            positions = positions[keep]
            if len(positions) == 0:
                return None
        pts, tris, nrm = gprims.point_spheres(positions, widths)
        row = self.material_row(prim, prim, False)
        return _Chunk(pts, tris, np.full(len(tris), row, np.uint32), nrm[tris], None)

    def curves_chunk(self, prim, world: np.ndarray | None = None) -> _Chunk | None:
        """A BasisCurves prim's tubes of triangles (in its local space), or None. With
        `world` (its transform; a prim of the world, not of a prototype) a still,
        non-emissive prim goes to self.curves as Embree round curves instead and None is
        returned: moving curves need an instance's matrices, and only triangles are lights."""
        paths = curves.curve_paths(prim, self.time, self._count_note)
        if paths is None:
            return None
        row = self.material_row(prim, prim, False)
        emissive = any(float(x) > 0 for x in self.materials.rows[row]["values"]["emissiveColor"])
        if world is not None and not emissive and \
                self.motion_steps(prim, np.vstack([p for p, _, _ in paths])) is None:
            self._add_native_curves(prim, paths, world, row)
            return None
        pts, tris, normals, _ = curves.curves_geometry(paths)
        return _Chunk(pts, tris, np.full(len(tris), row, np.uint32), normals, None)

    def _add_native_curves(self, prim, paths, world: np.ndarray, row: int) -> None:
        pts, segs, flags = curves.native_curves(paths, world, self._count_note)
        if not np.isfinite(pts).all():
            self.warn(f"{prim.GetPath()}: BasisCurves with NaN/Inf points or widths skipped")
            return
        # A segment costs Embree about what a triangle does: both count toward the limit.
        self.count_primitives(len(segs), str(prim.GetPath()))
        base = sum(len(p) for p in self.curves["points"])
        self.curves["points"].append(pts)
        self.curves["segments"].append(segs + np.uint32(base))
        self.curves["flags"].append(flags)
        self.curves["material"].append(np.full(len(segs), row, np.uint32))


def _posed_points(skel_query, query, time) -> np.ndarray | None:
    """A skinned mesh's points posed at `time`, in the skeleton's space, or None."""
    points = _skinnable_points(query.GetPrim(), time)
    xforms = skel_query.ComputeSkinningTransforms(time)
    if points is None or xforms is None:
        return None
    if query.IsRigidlyDeformed():
        m = np.array(query.ComputeSkinnedTransform(xforms, time), np.float64)
        return np.asarray(points, np.float64) @ m[:3, :3] + m[3, :3]
    if not query.ComputeSkinnedPoints(xforms, points, time):
        return None
    return np.asarray(points, np.float64)


def _skinnable_points(prim, time):
    """A mesh's points at `time` as a mutable Vt array (the skinning query writes into it)."""
    from pxr import UsdGeom, Vt

    value = UsdGeom.PointBased(prim).GetPointsAttr().Get(time) if UsdGeom.PointBased(prim) else None
    return Vt.Vec3fArray(value) if value is not None else None


def _normalized(v: np.ndarray) -> np.ndarray:
    with np.errstate(all="ignore"):
        return v / np.sqrt(np.einsum("...i,...i->...", v, v))[..., None]


def _float_rows(value, width: int | None, dtype=np.float64) -> np.ndarray | None:
    """A USD array value as float64 (N, width), or None when it is not an array of
    width-vectors (files do author scalars or ints where arrays of vectors belong)."""
    try:
        a = np.asarray(value)
    except Exception:
        return None
    if a.ndim == 1 and width is None and a.dtype.kind == "f":
        a = a[:, None]
    if a.ndim != 2 or a.dtype.kind != "f" or (width is not None and a.shape[1] != width):
        return None
    return a.astype(dtype, copy=False)


def _float_rows32(value, width: int | None) -> np.ndarray | None:
    return _float_rows(value, width, np.float32)


def _ints(value) -> np.ndarray | None:
    try:
        a = np.asarray(value)
    except Exception:
        return None
    if a.ndim != 1 or a.dtype.kind not in "iu":
        return None
    return a.astype(np.int64, copy=False)


def _triangulate_corners(counts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Fan triangulation in face-vertex space: face with n vertices -> n-2 triangles
    (c0, ck, ck+1) as indices into faceVertexIndices, and the face of each triangle.
    Faces with fewer than 3 vertices yield nothing. Vectorised over all faces."""
    starts = np.cumsum(counts) - counts
    n_tris = np.maximum(counts - 2, 0)
    total = int(n_tris.sum())
    if total == 0:
        return np.zeros((0, 3), dtype=np.int64), np.zeros(0, dtype=np.int64)
    face = np.repeat(np.arange(len(counts)), n_tris)
    face_start = starts[face]
    first_tri = np.cumsum(n_tris) - n_tris
    k = np.arange(total) - first_tri[face] + 1
    return np.stack([face_start, face_start + k, face_start + k + 1], axis=1), face


def _split_concave_quads(corners, counts, face_indices, points) -> None:
    """A concave quad whose reflex vertex is corner 1 or 3 puts the fan's diagonal 0-2
    outside it: split those along 1-3 instead (in place, vectorised over all quads)."""
    n_tris = np.maximum(counts - 2, 0)
    quads = np.nonzero(counts == 4)[0]
    if len(quads) == 0:
        return
    first = (np.cumsum(n_tris) - n_tris)[quads]
    pts32 = points.astype(np.float32)
    for at in range(0, len(first), 1 << 18):  # in slices: bounded temporaries
        t0 = first[at:at + (1 << 18)]
        c0, c1, c2 = corners[t0].T
        c3 = corners[t0 + 1, 2]
        p = pts32[face_indices[np.stack([c0, c1, c2, c3], axis=1)]]
        normal = np.cross(p[:, 2] - p[:, 0], p[:, 3] - p[:, 1])  # the quad's Newell normal (x2)
        bad = np.einsum("ij,ij->i", np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]), normal) < 0
        bad |= np.einsum("ij,ij->i", np.cross(p[:, 2] - p[:, 0], p[:, 3] - p[:, 0]), normal) < 0
        if bad.any():
            corners[t0[bad]] = np.stack([c1, c2, c3], axis=1)[bad]
            corners[t0[bad] + 1] = np.stack([c1, c3, c0], axis=1)[bad]


def _triangulate_fan(counts: np.ndarray, face_indices: np.ndarray) -> np.ndarray:
    """Fan-triangulates polygons into vertex-index triangles (see _triangulate_corners)."""
    corners, _ = _triangulate_corners(np.asarray(counts, np.int64))
    return np.asarray(face_indices)[corners]


def _expand(values, interp, indices, corners, tris, face_of_tri, shape):
    """Per-corner values (T, 3, k) from a primvar of any interpolation; None if the
    number of values does not fit the interpolation."""
    n_points, n_faces, n_fv = shape
    if indices is not None:
        n_values = len(indices)
    else:
        n_values = len(values)

    def take(i):
        return values[indices[i]] if indices is not None else values[i]

    if interp == "constant":
        if n_values < 1:
            return None
        return np.broadcast_to(take(np.array([0]))[0], (len(tris), 3, values.shape[1])).copy()
    if interp == "uniform":
        if n_values != n_faces:
            return None
        return np.repeat(take(face_of_tri)[:, None, :], 3, axis=1)
    if interp in ("vertex", "varying"):
        if n_values != n_points:
            return None
        return take(tris)
    if interp == "faceVarying":
        if n_values != n_fv:
            return None
        return take(corners)
    return None


def _face_normals(points: np.ndarray, tris: np.ndarray) -> np.ndarray:
    p = points[tris]
    n = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
    with np.errstate(all="ignore"):
        n = n / np.linalg.norm(n, axis=1, keepdims=True)
    return np.nan_to_num(n, nan=0.0)


def _vertex_normals(points: np.ndarray, tris: np.ndarray) -> np.ndarray:
    """Area-weighted smooth vertex normals, as per-corner (T, 3, 3)."""
    p = points[tris]
    fn = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
    acc = np.zeros_like(points)
    for c in range(3):
        np.add.at(acc, tris[:, c], fn)
    with np.errstate(all="ignore"):
        acc /= np.linalg.norm(acc, axis=1, keepdims=True)
    return np.nan_to_num(acc, nan=0.0)[tris]
