#include "bench/exported_frames.h"

#include "io/hdf5_util.h"

#include <hdf5.h>

#include <filesystem>

namespace fc {

namespace {

using hdf5::checked;
using hdf5::Handle;

class FramesReader {
 public:
  explicit FramesReader(const std::string& path) : path_(path), file_(open(path), H5Fclose) {}

  [[noreturn]] void fail(const std::string& what) const {
    const std::string detail = hdf5::takeError();
    throw ExportReadError("frames file '" + path_ + "': " + what +
                          (detail.empty() ? std::string() : " (HDF5: " + detail + ")"));
  }

  std::vector<double> doubles(const char* name) const {
    if (H5Aexists(file_.get(), name) <= 0) fail(std::string("has no '") + name + "' attribute");
    Handle a(checked(H5Aopen(file_.get(), name, H5P_DEFAULT)), H5Aclose);
    Handle space(a.ok() ? checked(H5Aget_space(a.get())) : -1, H5Sclose);
    const hssize_t n = space.ok() ? H5Sget_simple_extent_npoints(space.get()) : -1;
    if (n < 0) fail(std::string("cannot read the '") + name + "' attribute");
    std::vector<double> v(static_cast<size_t>(n));
    if (n > 0 && checked(H5Aread(a.get(), H5T_NATIVE_DOUBLE, v.data())) < 0)
      fail(std::string("cannot read the '") + name + "' attribute as numbers");
    return v;
  }

  // A whole dataset of `cols` columns (0: one-dimensional) in memType.
  template <class T>
  std::vector<T> dataset(const char* name, hid_t memType, int cols) const {
    // H5Lexists needs every group on the way to exist.
    const std::string group = std::string(name).substr(0, std::string(name).find('/', 1));
    if (H5Lexists(file_.get(), group.c_str(), H5P_DEFAULT) <= 0 || H5Lexists(file_.get(), name, H5P_DEFAULT) <= 0)
      fail(std::string("has no dataset ") + name);
    Handle ds(checked(H5Dopen2(file_.get(), name, H5P_DEFAULT)), H5Dclose);
    Handle space(ds.ok() ? checked(H5Dget_space(ds.get())) : -1, H5Sclose);
    hsize_t dims[2] = {0, 0};
    const int rank = space.ok() ? H5Sget_simple_extent_ndims(space.get()) : -1;
    if (rank != (cols > 0 ? 2 : 1) || H5Sget_simple_extent_dims(space.get(), dims, nullptr) < 0 ||
        (cols > 0 && dims[1] != hsize_t(cols)))
      fail(std::string("dataset ") + name + " has the wrong shape");
    std::vector<T> v(size_t(dims[0]) * size_t(cols > 0 ? cols : 1));
    if (!v.empty() && checked(H5Dread(ds.get(), memType, H5S_ALL, H5S_ALL, H5P_DEFAULT, v.data())) < 0)
      fail(std::string("cannot read dataset ") + name);
    return v;
  }

 private:
  static hid_t open(const std::string& path) {
    if (!std::filesystem::is_regular_file(path))
      throw ExportReadError("frames file '" + path + "': does not exist or is not a regular file");
    const hid_t f = checked(H5Fopen(path.c_str(), H5F_ACC_RDONLY, H5P_DEFAULT));
    if (f < 0) throw ExportReadError("frames file '" + path + "': cannot be opened as HDF5 (HDF5: " +
                                     hdf5::takeError() + ")");
    return f;
  }

  std::string path_;
  Handle file_;
};

}  // namespace

ExportedFrames readExportedFrames(const std::string& path) {
  hdf5::Quiet quiet;
  FramesReader r(path);
  ExportedFrames e;
  const auto dim = r.doubles("dimension");
  if (dim.size() != 1 || (dim[0] != 2 && dim[0] != 3)) r.fail("'dimension' must be 2 or 3");
  e.dimension = int(dim[0]);
  const auto radius = r.doubles("particle_radius");
  if (radius.size() != 1 || !(radius[0] > 0)) r.fail("'particle_radius' must be one positive number");
  e.particleRadius = radius[0];
  e.phaseRestDensity = r.doubles("phase_rest_density");
  e.time = r.dataset<double>("/frames/time", H5T_NATIVE_DOUBLE, 0);
  e.offset = r.dataset<uint64_t>("/frames/offset", H5T_NATIVE_UINT64, 0);
  e.position = r.dataset<float>("/particles/position", H5T_NATIVE_FLOAT, e.dimension);
  e.density = r.dataset<float>("/particles/density", H5T_NATIVE_FLOAT, 0);
  e.phase = r.dataset<uint8_t>("/particles/phase", H5T_NATIVE_UINT8, 0);
  e.kind = r.dataset<uint8_t>("/particles/kind", H5T_NATIVE_UINT8, 0);
  const size_t rows = e.density.size();
  if (e.offset.size() != e.time.size() + 1 || e.offset.front() != 0 || e.offset.back() != rows)
    r.fail("/frames/offset does not index the particle rows (" + std::to_string(e.offset.size()) + " offsets, " +
           std::to_string(e.time.size()) + " frames, " + std::to_string(rows) + " rows)");
  for (size_t f = 0; f + 1 < e.offset.size(); ++f)
    if (e.offset[f + 1] < e.offset[f]) r.fail("/frames/offset decreases at frame " + std::to_string(f));
  if (e.position.size() != rows * size_t(e.dimension) || e.phase.size() != rows || e.kind.size() != rows)
    r.fail("the particle datasets have different row counts");
  for (uint8_t p : e.phase)
    if (p >= e.phaseRestDensity.size()) r.fail("a particle's phase has no rest density");
  return e;
}

}  // namespace fc
