#include "io/template_file.h"

#include "io/hdf5_util.h"
#include "io/staged_files.h"

#include <hdf5.h>

#include <unistd.h>

#include <algorithm>
#include <array>
#include <atomic>
#include <cerrno>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <limits>
#include <numeric>
#include <regex>
#include <system_error>

namespace fc {

namespace {

namespace fs = std::filesystem;

using hdf5::checked;
using hdf5::Handle;
using hdf5::syncPath;
using hdf5::utf8StringType;
using hdf5::writeArray;
using hdf5::writeScalar;
using hdf5::writeString;

constexpr const char* kFormat = "flowclip-template";
// Rows per chunk of the particle datasets (at most; fewer for small files).
constexpr hsize_t kParticleChunkRows = 65536;
constexpr hsize_t kFrameChunkRows = 4096;
// Templates are written once and read often: size matters more than write
// speed (level 6 vs 1: see templates/README.md).
constexpr unsigned kDeflateLevel = 6;
// Position error bound of the uint16 encoding, as a fraction of the particle
// radius, and the quantization step used for it (slightly finer than twice
// the bound, leaving room for float rounding of the decoded value).
constexpr double kPositionErrorFraction = 0.01;
constexpr double kPositionStepFraction = 0.0198;
// Velocities: int16 values in -kVelocityLevels..kVelocityLevels times the
// frame's scale max|v_id| / kVelocityLevels. The full int16 range (32767)
// costs ~1.7 bytes per particle-frame more in 3D on liquid data (velocity
// noise fills the low bits) and misses the 7-byte target.
constexpr double kVelocityLevels = 1023;

[[noreturn]] void fail(const std::string& path, const std::string& what) {
  throw TemplateError("template file '" + path + "': " + what);
}

// `what`, with the text of the first HDF5 failure since the Quiet guard.
[[noreturn]] void failHdf5(const std::string& path, const std::string& what) {
  const std::string detail = hdf5::takeError();
  fail(path, what + (detail.empty() ? std::string() : " (HDF5: " + detail + ")"));
}

bool writeInt(hid_t loc, const char* name, int64_t v) {
  return writeScalar(loc, name, H5T_STD_I64LE, H5T_NATIVE_INT64, &v);
}
bool writeDouble(hid_t loc, const char* name, double v) {
  return writeScalar(loc, name, H5T_IEEE_F64LE, H5T_NATIVE_DOUBLE, &v);
}
bool writeDoubles(hid_t loc, const char* name, const std::vector<double>& v) {
  return v.empty() ? hdf5::writeEmpty(loc, name, H5T_IEEE_F64LE)
                   : writeArray(loc, name, H5T_IEEE_F64LE, H5T_NATIVE_DOUBLE, v.size(), v.data());
}

// A chunked, shuffled (multi-byte types) and deflated dataset of `rows` rows
// and `cols` columns (0: one-dimensional), extendible along rows, written
// whole from `data`.
bool writeDataset(hid_t file, const char* name, hid_t fileType, hid_t memType, hsize_t rows, int cols,
                  hsize_t maxChunkRows, const void* data) {
  Handle ds(hdf5::createDataset(file, name, fileType, rows, cols, std::clamp<hsize_t>(rows, 1, maxChunkRows),
                                kDeflateLevel),
            H5Dclose);
  if (!ds.ok()) return false;
  if (rows == 0) return true;
  return checked(H5Dwrite(ds.get(), memType, H5S_ALL, H5S_ALL, H5P_DEFAULT, data)) >= 0;
}

// Morton code of D 16-bit grid coordinates (bit b of axis d at b*D + d).
template <int D>
uint64_t morton(const std::array<uint16_t, D>& g) {
  uint64_t key = 0;
  for (int b = 0; b < 16; ++b)
    for (int d = 0; d < D; ++d) key |= uint64_t((g[d] >> b) & 1u) << (b * D + d);
  return key;
}

bool finite(double v) { return std::isfinite(v); }

// ---------------------------------------------------------------------------
// Reading.

class Reader {
 public:
  static hid_t open(const std::string& path) {
    std::error_code ec;
    const auto st = fs::status(path, ec);
    if (!fs::exists(st)) fail(path, "does not exist");
    if (!fs::is_regular_file(st)) fail(path, "is not a regular file");
    if (H5Fis_hdf5(path.c_str()) <= 0)
      fail(path, "is not an HDF5 file (no HDF5 signature: wrong kind of file, or corrupt)");
    Handle fapl(checked(H5Pcreate(H5P_FILE_ACCESS)), H5Pclose);
    if (!fapl.ok() || checked(H5Pset_fclose_degree(fapl.get(), H5F_CLOSE_STRONG)) < 0)
      failHdf5(path, "cannot set up the file access properties");
    const hid_t f = checked(H5Fopen(path.c_str(), H5F_ACC_RDONLY, fapl.get()));
    if (f < 0) failHdf5(path, "cannot be opened as HDF5 (truncated or corrupt?)");
    return f;
  }
  explicit Reader(const std::string& path) : path_(path), file_(open(path), H5Fclose) {}
  hid_t file() const { return file_.get(); }
  const std::string& path() const { return path_; }

  bool hasAttr(const char* name) const { return H5Aexists(file(), name) > 0; }

  Handle openAttr(const char* name) const {
    if (!hasAttr(name)) fail(path_, std::string("has no '") + name + "' attribute");
    Handle a(checked(H5Aopen(file(), name, H5P_DEFAULT)), H5Aclose);
    if (!a.ok()) failHdf5(path_, std::string("cannot open the '") + name + "' attribute");
    return a;
  }

  // Number of elements of an attribute's dataspace (1 for scalars).
  hssize_t attrSize(hid_t attr) const {
    Handle space(checked(H5Aget_space(attr)), H5Sclose);
    return space.ok() ? checked(H5Sget_simple_extent_npoints(space.get())) : -1;
  }

  std::string string(const char* name) const {
    Handle a = openAttr(name);
    Handle type(H5Aget_type(a.get()), H5Tclose);
    if (!type.ok() || H5Tget_class(type.get()) != H5T_STRING || attrSize(a.get()) != 1)
      fail(path_, std::string("attribute '") + name + "' is not a string");
    if (H5Tis_variable_str(type.get()) > 0) {
      // Read with the attribute's own type: HDF5 1.10 does not convert
      // between character sets (ASCII and UTF-8 strings both occur).
      Handle mem(checked(H5Tcopy(type.get())), H5Tclose);
      char* p = nullptr;
      if (!mem.ok() || checked(H5Aread(a.get(), mem.get(), &p)) < 0)
        failHdf5(path_, std::string("cannot read the '") + name + "' attribute");
      std::string s = p ? p : "";
      Handle space(H5Aget_space(a.get()), H5Sclose);
      H5Dvlen_reclaim(mem.get(), space.get(), H5P_DEFAULT, &p);
      return s;
    }
    const size_t n = H5Tget_size(type.get());
    std::string s(n, '\0');
    Handle mem(checked(H5Tcopy(H5T_C_S1)), H5Tclose);
    if (!mem.ok() || checked(H5Tset_size(mem.get(), n + 1)) < 0) failHdf5(path_, "cannot set up a string type");
    std::vector<char> buf(n + 1, '\0');
    if (checked(H5Aread(a.get(), mem.get(), buf.data())) < 0)
      failHdf5(path_, std::string("cannot read the '") + name + "' attribute");
    return std::string(buf.data());
  }

  std::vector<double> doubles(const char* name, hssize_t expected) const {
    Handle a = openAttr(name);
    Handle type(H5Aget_type(a.get()), H5Tclose);
    const H5T_class_t cls = type.ok() ? H5Tget_class(type.get()) : H5T_NO_CLASS;
    if (cls != H5T_FLOAT && cls != H5T_INTEGER) fail(path_, std::string("attribute '") + name + "' is not numeric");
    const hssize_t n = attrSize(a.get());
    if (expected >= 0 && n != expected)
      fail(path_, std::string("attribute '") + name + "' has " + std::to_string(n) + " values, expected " +
                      std::to_string(expected));
    if (n < 0) failHdf5(path_, std::string("cannot read the '") + name + "' attribute");
    std::vector<double> v(static_cast<size_t>(n));
    if (n > 0 && checked(H5Aread(a.get(), H5T_NATIVE_DOUBLE, v.data())) < 0)
      failHdf5(path_, std::string("cannot read the '") + name + "' attribute");
    for (double x : v)
      if (!finite(x)) fail(path_, std::string("attribute '") + name + "' is not finite");
    return v;
  }
  double number(const char* name) const { return doubles(name, 1)[0]; }

  int64_t integer(const char* name) const {
    Handle a = openAttr(name);
    Handle type(H5Aget_type(a.get()), H5Tclose);
    if (!type.ok() || H5Tget_class(type.get()) != H5T_INTEGER || attrSize(a.get()) != 1)
      fail(path_, std::string("attribute '") + name + "' is not an integer");
    int64_t v = 0;
    if (checked(H5Aread(a.get(), H5T_NATIVE_INT64, &v)) < 0)
      failHdf5(path_, std::string("cannot read the '") + name + "' attribute");
    return v;
  }

  // Opens a dataset and checks its element type and shape: `cols` 0 means
  // one-dimensional, otherwise [rows, cols]. Returns rows.
  Handle openDataset(const char* name, H5T_class_t cls, size_t size, int sign, int cols, hsize_t* rows) const {
    if (H5Lexists(file(), "/frames", H5P_DEFAULT) <= 0 || H5Lexists(file(), "/particles", H5P_DEFAULT) <= 0 ||
        H5Lexists(file(), name, H5P_DEFAULT) <= 0)
      fail(path_, std::string("has no dataset ") + name);
    Handle ds(checked(H5Dopen2(file(), name, H5P_DEFAULT)), H5Dclose);
    if (!ds.ok()) failHdf5(path_, std::string("cannot open dataset ") + name);
    Handle type(H5Dget_type(ds.get()), H5Tclose);
    const bool typeOk = type.ok() && H5Tget_class(type.get()) == cls && H5Tget_size(type.get()) == size &&
                        (cls != H5T_INTEGER || int(H5Tget_sign(type.get())) == sign);
    if (!typeOk) fail(path_, std::string("dataset ") + name + " has the wrong element type");
    Handle space(H5Dget_space(ds.get()), H5Sclose);
    const int rank = space.ok() ? H5Sget_simple_extent_ndims(space.get()) : -1;
    hsize_t dims[2] = {0, 0};
    if (rank != (cols > 0 ? 2 : 1) || H5Sget_simple_extent_dims(space.get(), dims, nullptr) < 0 ||
        (cols > 0 && dims[1] != hsize_t(cols)))
      fail(path_, std::string("dataset ") + name + " has the wrong shape" +
                      (cols > 0 ? " (expected [N, " + std::to_string(cols) + "])" : " (expected one-dimensional)"));
    *rows = dims[0];
    return ds;
  }

  template <class T>
  std::vector<T> read(const Handle& ds, hid_t memType, size_t elements, const char* name) const {
    std::vector<T> v(elements);
    if (elements > 0 && checked(H5Dread(ds.get(), memType, H5S_ALL, H5S_ALL, H5P_DEFAULT, v.data())) < 0)
      failHdf5(path_, std::string("cannot read dataset ") + name + " (truncated or corrupt?)");
    return v;
  }

  // The frame-offset index, validated against `frames` and `rows`.
  std::vector<uint64_t> offsets(size_t frames, hsize_t rows) const {
    hsize_t n = 0;
    Handle ds = openDataset("/frames/offset", H5T_INTEGER, 8, H5T_SGN_NONE, 0, &n);
    if (n != frames + 1)
      fail(path_, "/frames/offset has " + std::to_string(n) + " entries, expected frame_count + 1 = " +
                      std::to_string(frames + 1));
    auto off = read<uint64_t>(ds, H5T_NATIVE_UINT64, n, "/frames/offset");
    if (off[0] != 0) fail(path_, "/frames/offset does not start at 0");
    for (size_t f = 0; f < frames; ++f)
      if (off[f + 1] < off[f]) fail(path_, "/frames/offset decreases at frame " + std::to_string(f));
    if (off[frames] != rows)
      fail(path_, "/frames/offset ends at " + std::to_string(off[frames]) + " but the particle datasets have " +
                      std::to_string(rows) + " rows");
    return off;
  }

  // Rows of the particle datasets, taken from /particles/phase.
  hsize_t particleRows() const {
    hsize_t n = 0;
    openDataset("/particles/phase", H5T_INTEGER, 1, H5T_SGN_NONE, 0, &n);
    return n;
  }

 private:
  std::string path_;
  Handle file_;
};

TemplateHeader readHeader(const Reader& r) {
  const std::string& path = r.path();
  if (!r.hasAttr("format")) fail(path, "is HDF5 but not a FlowClip template (no 'format' attribute)");
  const std::string format = r.string("format");
  if (format != kFormat)
    fail(path, "is HDF5 but not a FlowClip template (format is '" + format + "', expected '" + kFormat + "')");
  const int64_t version = r.integer("format_version");
  if (version != kTemplateFormatVersion)
    fail(path, "has format_version " + std::to_string(version) + "; this program reads format_version " +
                   std::to_string(kTemplateFormatVersion));
  TemplateHeader h;
  const int64_t dim = r.integer("dimension");
  if (dim != 2 && dim != 3) fail(path, "has dimension " + std::to_string(dim) + " (must be 2 or 3)");
  h.dimension = int(dim);
  h.name = r.string("name");
  h.frameRate = r.number("frame_rate");
  h.particleRadius = r.number("particle_radius");
  h.supportRadius = r.number("support_radius");
  h.restDensity = r.number("rest_density");
  if (!(h.frameRate > 0)) fail(path, "attribute 'frame_rate' must be positive");
  if (!(h.particleRadius > 0)) fail(path, "attribute 'particle_radius' must be positive");
  if (!(h.supportRadius > 0)) fail(path, "attribute 'support_radius' must be positive");
  if (!(h.restDensity > 0)) fail(path, "attribute 'rest_density' must be positive");
  h.regionMin = r.doubles("region_min", dim);
  h.regionMax = r.doubles("region_max", dim);
  for (int d = 0; d < h.dimension; ++d)
    if (h.regionMin[d] > h.regionMax[d]) fail(path, "region_min exceeds region_max on axis " + std::to_string(d));
  h.recipe = r.string("recipe");
  h.createdBy = r.string("created_by");
  if (r.integer("frame_count") < 0) fail(path, "attribute 'frame_count' is negative");
  r.number("duration");
  return h;
}

}  // namespace

// ---------------------------------------------------------------------------

template <int D>
void writeTemplate(const std::string& path, const Template<D>& tpl) {
  const TemplateHeader& h = tpl.header;
  auto invalid = [&](const std::string& what) { fail(path, "cannot write: " + what); };
  static const std::regex kName("[A-Za-z0-9_-]{1,64}");
  if (!std::regex_match(h.name, kName)) invalid("template name '" + h.name + "' is not [A-Za-z0-9_-]{1,64}");
  if (h.dimension != D)
    invalid("header dimension " + std::to_string(h.dimension) + " does not match the template's " + std::to_string(D));
  if (h.regionMin.size() != size_t(D) || h.regionMax.size() != size_t(D))
    invalid("region_min/region_max must have " + std::to_string(D) + " values");
  for (int d = 0; d < D; ++d)
    if (!finite(h.regionMin[d]) || !finite(h.regionMax[d]) || h.regionMin[d] > h.regionMax[d])
      invalid("the capture region is not a finite box");
  if (!(finite(h.frameRate) && h.frameRate > 0)) invalid("frame rate must be positive");
  if (!(finite(h.particleRadius) && h.particleRadius > 0)) invalid("particle radius must be positive");
  if (!(finite(h.supportRadius) && h.supportRadius > 0)) invalid("support radius must be positive");
  if (!(finite(h.restDensity) && h.restDensity > 0)) invalid("rest density must be positive");

  const size_t F = tpl.frames.size();
  size_t N = 0;
  std::vector<double> lo(h.regionMin), hi(h.regionMax);
  for (size_t f = 0; f < F; ++f) {
    const TemplateFrame<D>& fr = tpl.frames[f];
    const size_t n = fr.x.size();
    if (fr.v.size() != n || fr.mass.size() != n || fr.phase.size() != n)
      invalid("frame " + std::to_string(f) + " has particle arrays of different lengths");
    for (size_t i = 0; i < n; ++i) {
      if (!fr.x[i].allFinite() || !fr.v[i].allFinite() || !finite(fr.mass[i]))
        invalid("frame " + std::to_string(f) + " particle " + std::to_string(i) + " has a non-finite value");
      for (int d = 0; d < D; ++d) {
        lo[d] = std::min(lo[d], double(fr.x[i][d]));
        hi[d] = std::max(hi[d], double(fr.x[i][d]));
      }
    }
    N += n;
  }

  // Position encoding: uint16 steps of kPositionStepFraction * r from the
  // origin (the lower corner of region ∪ particles), if the box fits in
  // 65535 steps on every axis; float32 otherwise.
  const double r = h.particleRadius;
  std::vector<double> origin(lo), step(D);
  bool quantized = true;
  for (int d = 0; d < D; ++d) {
    step[d] = kPositionStepFraction * r;
    if ((hi[d] - lo[d]) / step[d] > 65535.0) quantized = false;
  }
  auto gridOf = [&](const Vec<D>& x) {  // nearest grid point (also the sort key in float32 mode)
    std::array<uint16_t, D> g;
    for (int d = 0; d < D; ++d) {
      const double s = quantized ? step[d] : std::max(hi[d] - lo[d], 1e-300) / 65535.0;
      g[d] = uint16_t(std::clamp(std::nearbyint((double(x[d]) - origin[d]) / s), 0.0, 65535.0));
    }
    return g;
  };
  if (quantized) {  // guarantee the bound on what the reader will compute
    const double bound = kPositionErrorFraction * r;
    for (const auto& fr : tpl.frames) {
      for (const auto& x : fr.x) {
        const auto g = gridOf(x);
        for (int d = 0; d < D; ++d)
          if (std::abs(double(Real(origin[d] + g[d] * step[d])) - double(x[d])) > bound) quantized = false;
      }
      if (!quantized) break;
    }
  }

  // Mass table (<= 256 distinct values) or one float64 per particle.
  std::vector<double> massTable;
  for (const auto& fr : tpl.frames) {
    for (Real m : fr.mass) {
      if (std::find(massTable.begin(), massTable.end(), double(m)) == massTable.end()) massTable.push_back(double(m));
      if (massTable.size() > 256) break;
    }
    if (massTable.size() > 256) break;
  }
  const bool massIndexed = massTable.size() <= 256;
  if (massIndexed) std::sort(massTable.begin(), massTable.end());

  // Encode every frame, particles sorted by Morton code.
  std::vector<uint64_t> offset(F + 1, 0);
  std::vector<double> velScale(F, 0);
  std::vector<uint16_t> posQ;
  std::vector<float> posF;
  if (quantized) posQ.resize(N * D); else posF.resize(N * D);
  std::vector<int16_t> velQ(N * D);
  std::vector<uint8_t> massIdx, phase(N);
  std::vector<double> mass;
  if (massIndexed) massIdx.resize(N); else mass.resize(N);
  std::vector<std::pair<uint64_t, uint32_t>> order;
  size_t row = 0;
  for (size_t f = 0; f < F; ++f) {
    const TemplateFrame<D>& fr = tpl.frames[f];
    const size_t n = fr.size();
    order.resize(n);
    double vmax = 0;
    for (size_t i = 0; i < n; ++i) {
      order[i] = {morton<D>(gridOf(fr.x[i])), uint32_t(i)};
      vmax = std::max(vmax, double(fr.v[i].cwiseAbs().maxCoeff()));
    }
    std::sort(order.begin(), order.end());
    const double scale = vmax / kVelocityLevels;
    velScale[f] = scale;
    for (size_t k = 0; k < n; ++k, ++row) {
      const size_t i = order[k].second;
      if (quantized) {
        const auto g = gridOf(fr.x[i]);
        for (int d = 0; d < D; ++d) posQ[row * D + d] = g[d];
      } else {
        for (int d = 0; d < D; ++d) posF[row * D + d] = float(fr.x[i][d]);
      }
      for (int d = 0; d < D; ++d)
        velQ[row * D + d] = scale > 0 ? int16_t(std::clamp(std::nearbyint(double(fr.v[i][d]) / scale),
                                                           -kVelocityLevels, kVelocityLevels))
                                      : int16_t(0);
      if (massIndexed)
        massIdx[row] = uint8_t(std::lower_bound(massTable.begin(), massTable.end(), double(fr.mass[i])) -
                               massTable.begin());
      else
        mass[row] = double(fr.mass[i]);
      phase[row] = fr.phase[i];
    }
    offset[f + 1] = row;
  }

  // Write to a temporary file next to `path`, then rename; its hidden name is
  // one recoverPublishing() deletes after a crash.
  const std::string tmp = stagingPath(path);
  hdf5::Quiet quiet;
  bool created = false;
  auto abandon = [&](const std::string& what, bool hdf5) {
    const std::string detail = hdf5 ? hdf5::takeError() : std::string();
    if (created) std::remove(tmp.c_str());
    fail(path, "cannot write: " + what + (detail.empty() ? std::string() : " (HDF5: " + detail + ")"));
  };
  {
    Handle fapl(checked(H5Pcreate(H5P_FILE_ACCESS)), H5Pclose);
    // HDF5 1.10 object format (readable by HDF5 >= 1.10, i.e. any current
    // h5py): compact groups and chunk indices save ~20 KB per file.
    if (!fapl.ok() || checked(H5Pset_fapl_sec2(fapl.get())) < 0 ||
        checked(H5Pset_fclose_degree(fapl.get(), H5F_CLOSE_STRONG)) < 0 ||
        checked(H5Pset_libver_bounds(fapl.get(), H5F_LIBVER_V110, H5F_LIBVER_V110)) < 0)
      abandon("cannot set up the file access properties", true);
    // EXCL: never truncate a file we did not create.
    Handle file(checked(H5Fcreate(tmp.c_str(), H5F_ACC_EXCL, H5P_DEFAULT, fapl.get())), H5Fclose);
    if (!file.ok()) abandon("cannot create the temporary file '" + tmp + "'", true);
    created = true;
    const hid_t fid = file.get();
    const char* posEnc = quantized ? "uint16" : "float32";
    bool ok = writeString(fid, "format", kFormat) && writeInt(fid, "format_version", kTemplateFormatVersion) &&
              writeString(fid, "name", h.name) && writeInt(fid, "dimension", D) &&
              writeDouble(fid, "frame_rate", h.frameRate) && writeInt(fid, "frame_count", int64_t(F)) &&
              writeDouble(fid, "duration", tpl.duration()) && writeDouble(fid, "particle_radius", h.particleRadius) &&
              writeDouble(fid, "support_radius", h.supportRadius) && writeDouble(fid, "rest_density", h.restDensity) &&
              writeDoubles(fid, "region_min", h.regionMin) && writeDoubles(fid, "region_max", h.regionMax) &&
              writeString(fid, "recipe", h.recipe) && writeString(fid, "created_by", h.createdBy) &&
              writeString(fid, "position_encoding", posEnc) &&
              writeString(fid, "velocity_encoding", "int16_frame_scale") &&
              writeInt(fid, "velocity_levels", int64_t(kVelocityLevels)) &&
              writeString(fid, "mass_encoding", massIndexed ? "table" : "float64");
    if (ok && quantized)
      ok = writeDoubles(fid, "position_origin", origin) && writeDoubles(fid, "position_step", step);
    if (ok && massIndexed) ok = writeDoubles(fid, "mass_table", massTable);
    if (!ok) abandon("cannot write the header attributes", true);
    {
      Handle g1(checked(H5Gcreate2(fid, "frames", H5P_DEFAULT, H5P_DEFAULT, H5P_DEFAULT)), H5Gclose);
      Handle g2(checked(H5Gcreate2(fid, "particles", H5P_DEFAULT, H5P_DEFAULT, H5P_DEFAULT)), H5Gclose);
      if (!g1.ok() || !g2.ok()) abandon("cannot create the /frames and /particles groups", true);
    }
    ok = writeDataset(fid, "/frames/offset", H5T_STD_U64LE, H5T_NATIVE_UINT64, F + 1, 0, kFrameChunkRows,
                      offset.data()) &&
         writeDataset(fid, "/frames/velocity_scale", H5T_IEEE_F64LE, H5T_NATIVE_DOUBLE, F, 0, kFrameChunkRows,
                      velScale.data()) &&
         (quantized ? writeDataset(fid, "/particles/position", H5T_STD_U16LE, H5T_NATIVE_UINT16, N, D,
                                   kParticleChunkRows, posQ.data())
                    : writeDataset(fid, "/particles/position", H5T_IEEE_F32LE, H5T_NATIVE_FLOAT, N, D,
                                   kParticleChunkRows, posF.data())) &&
         writeDataset(fid, "/particles/velocity", H5T_STD_I16LE, H5T_NATIVE_INT16, N, D, kParticleChunkRows,
                      velQ.data()) &&
         (massIndexed ? writeDataset(fid, "/particles/mass_index", H5T_STD_U8LE, H5T_NATIVE_UINT8, N, 0,
                                     kParticleChunkRows, massIdx.data())
                      : writeDataset(fid, "/particles/mass", H5T_IEEE_F64LE, H5T_NATIVE_DOUBLE, N, 0,
                                     kParticleChunkRows, mass.data())) &&
         writeDataset(fid, "/particles/phase", H5T_STD_U8LE, H5T_NATIVE_UINT8, N, 0, kParticleChunkRows,
                      phase.data());
    if (!ok) abandon("cannot write the particle datasets", true);
    if (checked(H5Fflush(fid, H5F_SCOPE_LOCAL)) < 0) abandon("cannot write the temporary file '" + tmp + "'", true);
  }  // H5Fclose (strong: no object left open)
  try {
    syncPath(tmp, false);
  } catch (const std::system_error& e) {
    abandon("cannot flush '" + tmp + "' to disk: " + e.code().message(), false);
  }
  if (std::rename(tmp.c_str(), path.c_str()) != 0)
    abandon("cannot rename '" + tmp + "' to the final name: " + std::strerror(errno), false);
  try {
    const fs::path dir = fs::path(path).parent_path();
    syncPath(dir.empty() ? "." : dir.string(), true);
  } catch (const std::exception&) {
  }  // already published
}

TemplateHeader readTemplateHeader(const std::string& path) {
  hdf5::Quiet quiet;
  Reader r(path);
  return readHeader(r);
}

template <int D>
Template<D> readTemplate(const std::string& path) {
  hdf5::Quiet quiet;
  Reader r(path);
  Template<D> tpl;
  tpl.header = readHeader(r);
  if (tpl.header.dimension != D)
    fail(path, "is a " + std::to_string(tpl.header.dimension) + "D template, expected a " + std::to_string(D) +
                   "D one");
  const size_t F = size_t(r.integer("frame_count"));
  const std::string posEnc = r.string("position_encoding");
  const std::string velEnc = r.string("velocity_encoding");
  const std::string massEnc = r.string("mass_encoding");
  if (posEnc != "uint16" && posEnc != "float32") fail(path, "unknown position_encoding '" + posEnc + "'");
  if (velEnc != "int16_frame_scale") fail(path, "unknown velocity_encoding '" + velEnc + "'");
  if (massEnc != "table" && massEnc != "float64") fail(path, "unknown mass_encoding '" + massEnc + "'");
  const bool quantized = posEnc == "uint16";
  const bool massIndexed = massEnc == "table";

  const hsize_t N = r.particleRows();
  const std::vector<uint64_t> off = r.offsets(F, N);
  auto checkRows = [&](const char* name, hsize_t rows) {
    if (rows != N)
      fail(path, std::string(name) + " has " + std::to_string(rows) + " rows, /particles/phase has " +
                     std::to_string(N));
  };
  hsize_t rows = 0;
  Handle phaseDs = r.openDataset("/particles/phase", H5T_INTEGER, 1, H5T_SGN_NONE, 0, &rows);
  const auto phase = r.read<uint8_t>(phaseDs, H5T_NATIVE_UINT8, N, "/particles/phase");

  Handle scaleDs = r.openDataset("/frames/velocity_scale", H5T_FLOAT, 8, 0, 0, &rows);
  if (rows != F) fail(path, "/frames/velocity_scale has " + std::to_string(rows) + " entries, expected frame_count");
  const auto velScale = r.read<double>(scaleDs, H5T_NATIVE_DOUBLE, F, "/frames/velocity_scale");
  for (size_t f = 0; f < F; ++f)
    if (!finite(velScale[f]) || velScale[f] < 0)
      fail(path, "/frames/velocity_scale of frame " + std::to_string(f) + " is negative or not finite");

  Handle velDs = r.openDataset("/particles/velocity", H5T_INTEGER, 2, H5T_SGN_2, D, &rows);
  checkRows("/particles/velocity", rows);
  const auto velQ = r.read<int16_t>(velDs, H5T_NATIVE_INT16, N * D, "/particles/velocity");

  std::vector<double> origin, step;
  std::vector<uint16_t> posQ;
  std::vector<float> posF;
  if (quantized) {
    origin = r.doubles("position_origin", D);
    step = r.doubles("position_step", D);
    for (double s : step)
      if (!(s > 0)) fail(path, "attribute 'position_step' must be positive");
    Handle ds = r.openDataset("/particles/position", H5T_INTEGER, 2, H5T_SGN_NONE, D, &rows);
    checkRows("/particles/position", rows);
    posQ = r.read<uint16_t>(ds, H5T_NATIVE_UINT16, N * D, "/particles/position");
  } else {
    Handle ds = r.openDataset("/particles/position", H5T_FLOAT, 4, 0, D, &rows);
    checkRows("/particles/position", rows);
    posF = r.read<float>(ds, H5T_NATIVE_FLOAT, N * D, "/particles/position");
    for (size_t i = 0; i < posF.size(); ++i)
      if (!std::isfinite(posF[i])) fail(path, "/particles/position row " + std::to_string(i / D) + " is not finite");
  }

  std::vector<double> massTable, mass;
  std::vector<uint8_t> massIdx;
  if (massIndexed) {
    massTable = r.doubles("mass_table", -1);
    if (massTable.empty() && N > 0) fail(path, "attribute 'mass_table' is empty");
    Handle ds = r.openDataset("/particles/mass_index", H5T_INTEGER, 1, H5T_SGN_NONE, 0, &rows);
    checkRows("/particles/mass_index", rows);
    massIdx = r.read<uint8_t>(ds, H5T_NATIVE_UINT8, N, "/particles/mass_index");
    for (size_t i = 0; i < N; ++i)
      if (massIdx[i] >= massTable.size())
        fail(path, "/particles/mass_index row " + std::to_string(i) + " is outside mass_table");
  } else {
    Handle ds = r.openDataset("/particles/mass", H5T_FLOAT, 8, 0, 0, &rows);
    checkRows("/particles/mass", rows);
    mass = r.read<double>(ds, H5T_NATIVE_DOUBLE, N, "/particles/mass");
    for (size_t i = 0; i < N; ++i)
      if (!finite(mass[i])) fail(path, "/particles/mass row " + std::to_string(i) + " is not finite");
  }

  tpl.frames.resize(F);
  for (size_t f = 0; f < F; ++f) {
    TemplateFrame<D>& fr = tpl.frames[f];
    const size_t a = off[f], n = off[f + 1] - off[f];
    fr.x.resize(n);
    fr.v.resize(n);
    fr.mass.resize(n);
    fr.phase.assign(phase.begin() + a, phase.begin() + a + n);
    for (size_t k = 0; k < n; ++k) {
      const size_t row = a + k;
      for (int d = 0; d < D; ++d) {
        fr.x[k][d] = quantized ? Real(origin[d] + posQ[row * D + d] * step[d]) : Real(posF[row * D + d]);
        fr.v[k][d] = Real(velQ[row * D + d] * velScale[f]);
      }
      fr.mass[k] = Real(massIndexed ? massTable[massIdx[row]] : mass[row]);
    }
  }
  return tpl;
}

TemplateFileStats templateFileStats(const std::string& path) {
  hdf5::Quiet quiet;
  Reader r(path);
  readHeader(r);
  TemplateFileStats s;
  s.frames = size_t(r.integer("frame_count"));
  const hsize_t N = r.particleRows();
  const auto off = r.offsets(s.frames, N);
  for (size_t f = 0; f < s.frames; ++f) {
    const size_t n = off[f + 1] - off[f];
    s.minParticles = f == 0 ? n : std::min(s.minParticles, n);
    s.maxParticles = std::max(s.maxParticles, n);
  }
  s.avgParticles = s.frames ? double(N) / double(s.frames) : 0.0;
  std::error_code ec;
  s.bytesOnDisk = fs::file_size(path, ec);
  if (ec) fail(path, "cannot get the file size: " + ec.message());
  s.bytesPerParticleFrame = N ? double(s.bytesOnDisk) / double(N) : 0.0;
  return s;
}

template void writeTemplate<2>(const std::string&, const Template<2>&);
template void writeTemplate<3>(const std::string&, const Template<3>&);
template Template<2> readTemplate<2>(const std::string&);
template Template<3> readTemplate<3>(const std::string&);

}  // namespace fc
