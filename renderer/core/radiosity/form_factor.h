// Form factors (Cohen & Wallace 1993, ch. 4). The point-to-polygon factor is exact:
// Lambert's contour integral over the polygon clipped to the receiver's hemisphere, so
// adjacent elements (a box's corner) get their factor without the 1/r^2 blow-up of disk
// approximations. Visibility is estimated separately by shadow rays through Embree
// toward fixed points on the source (Wallace et al. 1989: receiver point to source area).
#pragma once

#include <vector>

#include "scene.h"

namespace tessera {

// F from a differential area at x with unit normal n to the polygon `poly` (any winding),
// ignoring occlusion: (1/pi) of the polygon's projected solid angle above x's plane.
float PointToPolygonFormFactor(Vec3 x, Vec3 n, const std::vector<Vec3>& poly);
float PointToTriangleFormFactor(Vec3 x, Vec3 n, const Vec3 tri[3]);

// Unoccluded area-to-area F_{A->B} = (1/|A|) Int_A F_{dA->B} dA for planar convex
// polygons, by the midpoint rule over a fan of triangles, each cut into `cells_per_edge`^2
// similar sub-triangles (the inner integrand is exact).
float PolygonToPolygonFormFactor(const std::vector<Vec3>& a, const std::vector<Vec3>& b, int cells_per_edge);

// Fraction of the fixed points on triangle `src` (the centroids of its 4 half-edge
// sub-triangles) visible from x, by shadow rays; each end is offset by `eps` off its
// surface (normals nx, nsrc).
float TriangleVisibility(const Scene& scene, Vec3 x, Vec3 nx, const Vec3 src[3], Vec3 nsrc, float eps);

}  // namespace tessera
