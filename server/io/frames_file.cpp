#include "io/frames_file.h"

#include "io/hdf5_util.h"

#include <cmath>
#include <filesystem>

namespace fc {

using hdf5::checked;
using hdf5::Handle;

namespace {

std::vector<double> numbers(const FramesFile& f, hid_t file, const char* name) {
  if (H5Aexists(file, name) <= 0) f.fail(std::string("has no '") + name + "' attribute");
  Handle a(checked(H5Aopen(file, name, H5P_DEFAULT)), H5Aclose);
  Handle space(a.ok() ? checked(H5Aget_space(a.get())) : -1, H5Sclose);
  Handle type(a.ok() ? checked(H5Aget_type(a.get())) : -1, H5Tclose);
  const hssize_t n = space.ok() ? H5Sget_simple_extent_npoints(space.get()) : -1;
  const H5T_class_t cls = type.ok() ? H5Tget_class(type.get()) : H5T_NO_CLASS;
  if (n < 0 || (cls != H5T_INTEGER && cls != H5T_FLOAT))
    f.fail(std::string("the '") + name + "' attribute is not numeric");
  std::vector<double> v(static_cast<size_t>(n));
  if (n > 0 && checked(H5Aread(a.get(), H5T_NATIVE_DOUBLE, v.data())) < 0)
    f.fail(std::string("cannot read the '") + name + "' attribute as numbers");
  return v;
}

// A string attribute, or several (variable-length UTF-8 or ASCII).
std::vector<std::string> strings(const FramesFile& f, hid_t file, const char* name) {
  if (H5Aexists(file, name) <= 0) f.fail(std::string("has no '") + name + "' attribute");
  Handle a(checked(H5Aopen(file, name, H5P_DEFAULT)), H5Aclose);
  Handle type(a.ok() ? checked(H5Aget_type(a.get())) : -1, H5Tclose);
  Handle space(a.ok() ? checked(H5Aget_space(a.get())) : -1, H5Sclose);
  if (!type.ok() || H5Tget_class(type.get()) != H5T_STRING || H5Tis_variable_str(type.get()) <= 0 || !space.ok())
    f.fail(std::string("the '") + name + "' attribute is not a variable-length string");
  const hssize_t n = H5Sget_simple_extent_npoints(space.get());
  if (n < 0 || n > (1 << 20)) f.fail(std::string("the '") + name + "' attribute has an impossible size");
  std::vector<char*> p(static_cast<size_t>(n), nullptr);
  Handle mem(checked(H5Tcopy(type.get())), H5Tclose);
  if (n > 0 && (!mem.ok() || checked(H5Aread(a.get(), mem.get(), p.data())) < 0))
    f.fail(std::string("cannot read the '") + name + "' attribute");
  std::vector<std::string> out;
  for (char* s : p) out.emplace_back(s ? s : "");
  if (n > 0) H5Dvlen_reclaim(mem.get(), space.get(), H5P_DEFAULT, p.data());
  return out;
}

// A whole frame table (small: one row per frame).
template <class T>
std::vector<T> whole(const FramesFile& f, const char* name, hid_t memType) {
  return f.read<T>(name, memType, 0, 0, ~uint64_t(0));
}

}  // namespace

void FramesFile::fail(const std::string& what) const {
  const std::string detail = hdf5::takeError();
  throw FramesFileError("frames file '" + path_ + "': " + what + (detail.empty() ? std::string() : " (HDF5: " + detail + ")"));
}

FramesFile::FramesFile(const std::string& path) : path_(path) {
  hdf5::Quiet quiet;
  if (!std::filesystem::is_regular_file(path))
    throw FramesFileError("frames file '" + path + "': does not exist or is not a regular file");
  file_ = checked(H5Fopen(path.c_str(), H5F_ACC_RDONLY, H5P_DEFAULT));
  if (file_ < 0) throw FramesFileError("frames file '" + path + "': cannot be opened as HDF5 (HDF5: " + hdf5::takeError() + ")");
  try {
    const auto format = strings(*this, file_, "format");
    if (format.size() != 1 || format[0] != "flowclip-frames")
      fail("is not a FlowClip frames file (format '" + (format.empty() ? std::string() : format[0]) + "')");
    const auto version = numbers(*this, file_, "format_version");
    if (version.size() != 1 || version[0] != 1)
      fail("has format_version " + (version.empty() ? std::string("?") : std::to_string(int(version[0]))) +
           "; this flowclip reads version 1 (docs/export-format.md)");
    const auto dim = numbers(*this, file_, "dimension");
    if (dim.size() != 1 || (dim[0] != 2 && dim[0] != 3)) fail("'dimension' must be 2 or 3");
    dimension_ = int(dim[0]);
    const auto radius = numbers(*this, file_, "particle_radius");
    if (radius.size() != 1 || !(radius[0] > 0) || !std::isfinite(radius[0]))
      fail("'particle_radius' must be one positive finite number");
    particleRadius_ = radius[0];
    const auto rate = numbers(*this, file_, "frame_rate");
    if (rate.size() != 1 || !(rate[0] > 0) || !std::isfinite(rate[0]))
      fail("'frame_rate' must be one positive finite number");
    frameRate_ = rate[0];
    scene_ = strings(*this, file_, "scene").at(0);
    phaseRestDensity_ = numbers(*this, file_, "phase_rest_density");
    phaseNames_ = strings(*this, file_, "phase_names");
    time_ = whole<double>(*this, "/frames/time", H5T_NATIVE_DOUBLE);
    index_ = whole<uint32_t>(*this, "/frames/index", H5T_NATIVE_UINT32);
    offset_ = whole<uint64_t>(*this, "/frames/offset", H5T_NATIVE_UINT64);
    if (index_.size() != time_.size() || offset_.size() != time_.size() + 1 || offset_.front() != 0)
      fail("the frame tables disagree (" + std::to_string(time_.size()) + " times, " + std::to_string(index_.size()) +
           " indices, " + std::to_string(offset_.size()) + " offsets)");
    for (size_t f = 0; f + 1 < offset_.size(); ++f)
      if (offset_[f + 1] < offset_[f]) fail("/frames/offset decreases at frame " + std::to_string(f));
    for (const char* column : {"/particles/position", "/particles/velocity", "/particles/phase", "/particles/kind"})
      if (!has(column)) fail(std::string("has no dataset ") + column);
  } catch (...) {
    H5Fclose(file_);
    file_ = -1;
    throw;
  }
}

FramesFile::~FramesFile() {
  if (file_ >= 0) H5Fclose(file_);
}

bool FramesFile::has(const char* name) const {
  const std::string group = std::string(name).substr(0, std::string(name).find('/', 1));
  return H5Lexists(file_, group.c_str(), H5P_DEFAULT) > 0 && H5Lexists(file_, name, H5P_DEFAULT) > 0;
}

template <class T>
std::vector<T> FramesFile::read(const char* name, hid_t memType, int cols, uint64_t begin, uint64_t count) const {
  hdf5::Quiet quiet;
  if (!has(name)) fail(std::string("has no dataset ") + name);
  Handle ds(checked(H5Dopen2(file_, name, H5P_DEFAULT)), H5Dclose);
  Handle space(ds.ok() ? checked(H5Dget_space(ds.get())) : -1, H5Sclose);
  hsize_t dims[2] = {0, 0};
  const int rank = space.ok() ? H5Sget_simple_extent_ndims(space.get()) : -1;
  if (rank != (cols > 0 ? 2 : 1) || H5Sget_simple_extent_dims(space.get(), dims, nullptr) < 0 ||
      (cols > 0 && dims[1] != hsize_t(cols)))
    fail(std::string("dataset ") + name + " has the wrong shape");
  if (count == ~uint64_t(0)) count = dims[0] > begin ? dims[0] - begin : 0;
  if (begin + count > dims[0])
    fail(std::string("dataset ") + name + " has " + std::to_string(dims[0]) + " rows, fewer than the frame tables say (" +
         std::to_string(begin + count) + ")");
  const size_t width = size_t(cols > 0 ? cols : 1);
  std::vector<T> v(size_t(count) * width);
  if (count == 0) return v;
  const hsize_t start[2] = {begin, 0}, extent[2] = {count, hsize_t(width)};
  Handle mem(checked(H5Screate_simple(rank, extent, nullptr)), H5Sclose);
  if (checked(H5Sselect_hyperslab(space.get(), H5S_SELECT_SET, start, nullptr, extent, nullptr)) < 0 || !mem.ok() ||
      checked(H5Dread(ds.get(), memType, mem.get(), space.get(), H5P_DEFAULT, v.data())) < 0)
    fail(std::string("cannot read dataset ") + name);
  return v;
}

template std::vector<float> FramesFile::read<float>(const char*, hid_t, int, uint64_t, uint64_t) const;
template std::vector<double> FramesFile::read<double>(const char*, hid_t, int, uint64_t, uint64_t) const;
template std::vector<uint8_t> FramesFile::read<uint8_t>(const char*, hid_t, int, uint64_t, uint64_t) const;
template std::vector<uint32_t> FramesFile::read<uint32_t>(const char*, hid_t, int, uint64_t, uint64_t) const;
template std::vector<uint64_t> FramesFile::read<uint64_t>(const char*, hid_t, int, uint64_t, uint64_t) const;

ParticleFrame FramesFile::frame(size_t f) const {
  if (f >= frames()) fail("has no frame " + std::to_string(f));
  const uint64_t begin = offset_[f], n = offset_[f + 1] - offset_[f];
  ParticleFrame out;
  out.index = int(index_[f]);
  out.time = time_[f];
  const auto lift = [&](std::vector<float> v) {
    if (dimension_ == 3) return v;
    std::vector<float> three(size_t(n) * 3, 0.0f);
    for (size_t i = 0; i < n; ++i) three[3 * i] = v[2 * i], three[3 * i + 1] = v[2 * i + 1];
    return three;
  };
  out.position = lift(read<float>("/particles/position", H5T_NATIVE_FLOAT, dimension_, begin, n));
  out.velocity = lift(read<float>("/particles/velocity", H5T_NATIVE_FLOAT, dimension_, begin, n));
  out.phase = read<uint8_t>("/particles/phase", H5T_NATIVE_UINT8, 0, begin, n);
  out.kind = read<uint8_t>("/particles/kind", H5T_NATIVE_UINT8, 0, begin, n);
  if (has("/particles/id")) out.id = read<uint32_t>("/particles/id", H5T_NATIVE_UINT32, 0, begin, n);
  if (has("/particles/density")) out.density = read<float>("/particles/density", H5T_NATIVE_FLOAT, 0, begin, n);
  return out;
}

}  // namespace fc
