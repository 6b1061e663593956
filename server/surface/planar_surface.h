#pragma once
// A 2D liquid's surface, made in its plane: the field on 8 × 8-node tiles,
// marching squares for its outline, a flat area mesh whose interior tiles
// are one fan each, and from these the slab or flat mesh and the level set
// a DCC takes (surface/surface.h's reconstructSurface with dimension 2).
#include "surface/particle_buckets.h"
#include "surface/surface.h"

namespace fc::surface_detail {

// Fills `out` (mesh, outline, grids, stage times) from the particles of a
// 2D frame, all at z = 0; `out.particles` is set by the caller.
void reconstructPlanar(const Buckets& buckets, double particleRadius, const SurfaceSettings& settings, bool withMesh,
                       bool withGrids, Surface& out);

}  // namespace fc::surface_detail
