#pragma once
// The OpenVDB grids of a Surface (surface/surface.h), for the code that
// writes them: a narrow-band level set `surface` (negative inside, world
// units) and the velocity `v`, the kernel-weighted mean velocity of the
// particles around each of its voxels.
#include <openvdb/openvdb.h>

#include <memory>

namespace fc {

struct SurfaceVolumes {
  openvdb::FloatGrid::Ptr surface;
  openvdb::Vec3SGrid::Ptr velocity;
};

// Empty grids on voxels `voxel` m wide, the level set's outside at `band`,
// for the reconstruction to fill (surface/surface.cpp, planar_surface.cpp).
inline SurfaceVolumes emptySurfaceVolumes(double voxel, float band) {
  SurfaceVolumes g{openvdb::FloatGrid::create(band), openvdb::Vec3SGrid::create(openvdb::Vec3s(0.0f))};
  g.surface->setTransform(openvdb::math::Transform::createLinearTransform(voxel));
  g.surface->setGridClass(openvdb::GRID_LEVEL_SET);
  g.surface->setName("surface");
  g.velocity->setTransform(g.surface->transform().copy());
  g.velocity->setName("v");
  g.velocity->setVectorType(openvdb::VEC_CONTRAVARIANT_RELATIVE);
  return g;
}

// The filled grids, their uniform leaves merged into tiles.
inline std::shared_ptr<SurfaceVolumes> prunedSurfaceVolumes(SurfaceVolumes g) {
  g.surface->pruneGrid();
  g.velocity->pruneGrid();
  return std::make_shared<SurfaceVolumes>(std::move(g));
}

}  // namespace fc
