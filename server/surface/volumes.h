#pragma once
// The OpenVDB grids of a Surface (surface/surface.h), for the code that
// writes them: a narrow-band level set `surface` (negative inside, world
// units) and the velocity `v`, the kernel-weighted mean velocity of the
// particles around each of its voxels.
#include <openvdb/openvdb.h>

namespace fc {

struct SurfaceVolumes {
  openvdb::FloatGrid::Ptr surface;
  openvdb::Vec3SGrid::Ptr velocity;
};

}  // namespace fc
