// The template file (HDF5) read and written in one place, so that the
// format's every dataset and its checks on reading stay side by side.
#include "io/template_file.h"

#include "io/hdf5_util.h"
#include "io/staged_files.h"

#include <hdf5.h>

#include <fcntl.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>
#include <zlib.h>

#include <algorithm>
#include <array>
#include <atomic>
#include <cerrno>
#include <charconv>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <limits>
#include <memory>
#include <mutex>
#include <numeric>
#include <optional>
#include <regex>
#include <string_view>
#include <system_error>

namespace fc {

namespace {

namespace fs = std::filesystem;

using hdf5::checked;
using hdf5::Handle;
using hdf5::utf8StringType;
using hdf5::writeArray;
using hdf5::writeScalar;
using hdf5::writeString;

constexpr const char* kFormat = "flowclip-template";
const std::regex kNamePattern("[A-Za-z0-9_-]{1,64}");
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
// The checksum block: the file's first 512 bytes are an HDF5 user block
// (HDF5 skips it) holding, as text, the CRC-32 and length of the rest.

constexpr size_t kChecksumBlockSize = 512;  // HDF5's smallest user block
constexpr std::string_view kChecksumMagic = "FLOWCLIP TEMPLATE\n";
constexpr unsigned char kHdf5Signature[8] = {0x89, 'H', 'D', 'F', '\r', '\n', 0x1a, '\n'};

uint32_t crc32Of(uint32_t crc, const unsigned char* p, size_t n) { return uint32_t(crc32_z(crc, p, n)); }

std::string checksumBlock(uint32_t crc, uint64_t length) {
  char text[96];
  std::snprintf(text, sizeof text, "crc32 %08x\nlength %llu\n", unsigned(crc), static_cast<unsigned long long>(length));
  std::string block = std::string(kChecksumMagic) + text;
  block.resize(kChecksumBlockSize, '\0');
  return block;
}

// The CRC and length of a block exactly as checksumBlock writes it.
bool parseChecksumBlock(const unsigned char* p, uint32_t* crc, uint64_t* length) {
  const std::string_view block(reinterpret_cast<const char*>(p), kChecksumBlockSize);
  constexpr std::string_view kCrc = "crc32 ", kLength = "\nlength ";
  size_t at = kChecksumMagic.size();
  if (block.substr(at, kCrc.size()) != kCrc) return false;
  at += kCrc.size();
  const char* end = block.data() + block.size();
  auto r = std::from_chars(block.data() + at, std::min(block.data() + at + 8, end), *crc, 16);
  if (r.ec != std::errc() || r.ptr != block.data() + at + 8) return false;
  at += 8;
  if (block.substr(at, kLength.size()) != kLength) return false;
  at += kLength.size();
  r = std::from_chars(block.data() + at, end, *length);
  return r.ec == std::errc() && block == checksumBlock(*crc, *length);
}

// Writes the checksum block over the (zero) user block of the closed HDF5
// file `path`. Returns what went wrong, empty on success.
std::string stampChecksum(const std::string& path) {
  const int fd = ::open(path.c_str(), O_RDWR | O_CLOEXEC);
  if (fd < 0) return std::strerror(errno);
  std::vector<unsigned char> buf(size_t(1) << 20);
  uint32_t crc = crc32Of(0, nullptr, 0);
  uint64_t length = 0;
  std::string error;
  for (;;) {
    const ssize_t got = ::pread(fd, buf.data(), buf.size(), off_t(kChecksumBlockSize + length));
    if (got < 0 && errno == EINTR) continue;
    if (got < 0) error = std::strerror(errno);
    if (got <= 0) break;
    crc = crc32Of(crc, buf.data(), size_t(got));
    length += uint64_t(got);
  }
  const std::string block = checksumBlock(crc, length);
  for (size_t done = 0; error.empty() && done < block.size();) {
    const ssize_t put = ::pwrite(fd, block.data() + done, block.size() - done, off_t(done));
    if (put < 0 && errno == EINTR) continue;
    if (put <= 0) error = put < 0 ? std::strerror(errno) : "short write";
    else done += size_t(put);
  }
  if (::close(fd) != 0 && error.empty()) error = std::strerror(errno);
  return error;
}

uint16_t le16(const unsigned char* p) { return uint16_t(p[0] | p[1] << 8); }
uint64_t le64(const unsigned char* p) {
  uint64_t v = 0;
  for (int i = 7; i >= 0; --i) v = v << 8 | p[i];
  return v;
}

// Well-formed UTF-8 (no overlong forms, surrogates or code points above
// U+10FFFF): strings go into JSON and error messages.
bool validUtf8(std::string_view s) {
  for (size_t i = 0; i < s.size();) {
    const auto c = uint8_t(s[i]);
    size_t n = 0;
    uint32_t cp = 0, min = 0;
    if (c < 0x80) n = 0, cp = c;
    else if ((c & 0xE0) == 0xC0) n = 1, cp = c & 0x1Fu, min = 0x80;
    else if ((c & 0xF0) == 0xE0) n = 2, cp = c & 0x0Fu, min = 0x800;
    else if ((c & 0xF8) == 0xF0) n = 3, cp = c & 0x07u, min = 0x10000;
    else return false;
    if (n > s.size() - i - 1) return false;
    for (size_t k = 1; k <= n; ++k) {
      const auto d = uint8_t(s[i + k]);
      if ((d & 0xC0) != 0x80) return false;
      cp = cp << 6 | (d & 0x3Fu);
    }
    if ((n > 0 && cp < min) || cp > 0x10FFFF || (cp >= 0xD800 && cp <= 0xDFFF)) return false;
    i += n + 1;
  }
  return true;
}

// A (valid UTF-8) string from the file for an error message, quoted: its
// first 64 bytes, cut at a character boundary.
std::string excerpt(const std::string& s) {
  if (s.size() <= 64) return "'" + s + "'";
  size_t cut = 64;
  while (cut > 0 && (uint8_t(s[cut]) & 0xC0) == 0x80) --cut;
  return "'" + s.substr(0, cut) + "...'";
}

// ---------------------------------------------------------------------------
// Reading.
//
// The file is read whole into memory and checked before HDF5 parses any of
// it, then HDF5 reads exactly those bytes (hdf5::openImage). HDF5 1.10
// verifies the checksums of its own metadata (the 1.10 object format has
// them) but not of the global heap that holds variable-length strings, nor
// of raw data; damaged heap bytes make it read and copy out of bounds.
// Files with a checksum block are verified whole; older files without one
// get their global heap checked the way HDF5 walks it.

// Compressed datasets hold at most this many bytes per stored byte (zlib's
// deflate tops out at 1032:1): a larger shape is damage, not data.
constexpr uint64_t kMaxDeflateRatio = 1100;
// Bytes of one chunk (HDF5 allocates a chunk per read; writeTemplate's are
// at most 65536 rows of 24 bytes).
constexpr uint64_t kMaxChunkBytes = uint64_t(64) << 20;

class Reader {
 public:
  explicit Reader(const std::string& path) : path_(path), image_(readImage(path)), file_(open(), H5Fclose) {}
  // From the disk instead of a copy in memory (TemplateStream): only files
  // with a checksum block, verified by reading the file through once.
  struct FromDisk {};
  Reader(const std::string& path, FromDisk) : path_(path), disk_(openDisk(path)), file_(openFromDisk(), H5Fclose) {}
  hid_t file() const { return file_.get(); }
  const std::string& path() const { return path_; }
  uint64_t fileSize() const { return disk_ ? disk_->size : image_.size(); }
  bool checksummed() const { return checksummed_; }

  bool hasAttr(const char* name) const {
    const htri_t exists = checked(H5Aexists(file(), name));
    if (exists < 0) failHdf5(path_, std::string("cannot look up the '") + name + "' attribute (damaged?)");
    return exists > 0;
  }

  Handle openAttr(const char* name) const {
    if (!hasAttr(name)) fail(path_, std::string("has no '") + name + "' attribute");
    Handle a(checked(H5Aopen(file(), name, H5P_DEFAULT)), H5Aclose);
    if (!a.ok()) failHdf5(path_, std::string("cannot open the '") + name + "' attribute");
    return a;
  }

  // Number of elements of an attribute's dataspace (1 for scalars, 0 for
  // null dataspaces), or -1.
  hssize_t attrSize(hid_t attr) const {
    Handle space(checked(H5Aget_space(attr)), H5Sclose);
    if (!space.ok()) return -1;
    switch (H5Sget_simple_extent_type(space.get())) {
      case H5S_NULL: return 0;
      case H5S_SCALAR: return 1;
      case H5S_SIMPLE: return checked(H5Sget_simple_extent_npoints(space.get()));
      default: return -1;
    }
  }

  std::string string(const char* name) const {
    Handle a = openAttr(name);
    Handle type(checked(H5Aget_type(a.get())), H5Tclose);
    const std::string what = std::string("attribute '") + name + "'";
    if (!type.ok() || H5Tget_class(type.get()) != H5T_STRING || attrSize(a.get()) != 1)
      fail(path_, what + " is not a string");
    const H5T_cset_t cset = H5Tget_cset(type.get());
    if (cset != H5T_CSET_ASCII && cset != H5T_CSET_UTF8) fail(path_, what + " is not a string");
    const htri_t variable = H5Tis_variable_str(type.get());
    std::string s;
    if (variable > 0) {
      // A scalar variable-length value is a 16-byte reference into the
      // global heap (length, collection address, index).
      if (H5Aget_storage_size(a.get()) != 16) fail(path_, "is damaged: " + what + " has the wrong storage size");
      // Read with the attribute's own type: HDF5 1.10 does not convert
      // between character sets (ASCII and UTF-8 strings both occur).
      Handle mem(checked(H5Tcopy(type.get())), H5Tclose);
      char* p = nullptr;
      if (!mem.ok() || checked(H5Aread(a.get(), mem.get(), &p)) < 0)
        failHdf5(path_, std::string("cannot read the '") + name + "' attribute");
      s = p ? p : "";
      Handle space(H5Aget_space(a.get()), H5Sclose);
      H5Dvlen_reclaim(mem.get(), space.get(), H5P_DEFAULT, &p);
    } else if (variable == 0) {
      const size_t n = H5Tget_size(type.get());
      if (n == 0 || n > fileSize()) fail(path_, "is damaged: " + what + " has an impossible size");
      Handle mem(checked(H5Tcopy(H5T_C_S1)), H5Tclose);
      if (!mem.ok() || checked(H5Tset_size(mem.get(), n + 1)) < 0) failHdf5(path_, "cannot set up a string type");
      std::vector<char> buf(n + 1, '\0');
      if (checked(H5Aread(a.get(), mem.get(), buf.data())) < 0)
        failHdf5(path_, std::string("cannot read the '") + name + "' attribute");
      s = buf.data();
    } else {
      fail(path_, what + " is not a string");
    }
    if (!validUtf8(s)) fail(path_, what + " is not valid UTF-8");
    return s;
  }

  std::vector<double> doubles(const char* name, hssize_t expected, hssize_t atMost = 0) const {
    Handle a = openAttr(name);
    Handle type(checked(H5Aget_type(a.get())), H5Tclose);
    if (!type.ok() || !plainNumber(type.get(), false))
      fail(path_, std::string("attribute '") + name + "' is not numeric");
    const hssize_t n = attrSize(a.get());
    if (n < 0) failHdf5(path_, std::string("cannot read the '") + name + "' attribute");
    if (expected >= 0 && n != expected)
      fail(path_, std::string("attribute '") + name + "' has " + std::to_string(n) + " values, expected " +
                      std::to_string(expected));
    if (expected < 0 && n > atMost)
      fail(path_, std::string("attribute '") + name + "' has " + std::to_string(n) + " values, at most " +
                      std::to_string(atMost) + " allowed");
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
    Handle type(checked(H5Aget_type(a.get())), H5Tclose);
    if (!type.ok() || !plainNumber(type.get(), true) || attrSize(a.get()) != 1)
      fail(path_, std::string("attribute '") + name + "' is not an integer");
    int64_t v = 0;
    if (checked(H5Aread(a.get(), H5T_NATIVE_INT64, &v)) < 0)
      failHdf5(path_, std::string("cannot read the '") + name + "' attribute");
    return v;
  }

  // Opens a dataset and checks, before anything of it is read, its element
  // type, shape (`cols` 0: one-dimensional, else [rows, cols]), storage
  // (chunked, with checksummed chunk index, known filters) and that its
  // size fits what the file can hold. Returns rows.
  Handle openDataset(const char* name, H5T_class_t cls, size_t size, int sign, int cols, hsize_t* rows) const {
    requireObject("/frames");
    requireObject("/particles");
    if (!requireObject(name)) fail(path_, std::string("has no dataset ") + name);
    Handle ds(checked(H5Dopen2(file(), name, H5P_DEFAULT)), H5Dclose);
    if (!ds.ok()) failHdf5(path_, std::string("cannot open dataset ") + name);
    Handle type(checked(H5Dget_type(ds.get())), H5Tclose);
    const bool typeOk = type.ok() && H5Tget_class(type.get()) == cls && H5Tget_size(type.get()) == size &&
                        plainNumber(type.get(), cls == H5T_INTEGER) &&
                        (cls != H5T_INTEGER || int(H5Tget_sign(type.get())) == sign);
    if (!typeOk) fail(path_, std::string("dataset ") + name + " has the wrong element type");
    Handle space(checked(H5Dget_space(ds.get())), H5Sclose);
    const int rank = space.ok() && H5Sget_simple_extent_type(space.get()) == H5S_SIMPLE
                         ? H5Sget_simple_extent_ndims(space.get())
                         : -1;
    hsize_t dims[2] = {0, 0};
    if (rank != (cols > 0 ? 2 : 1) || H5Sget_simple_extent_dims(space.get(), dims, nullptr) < 0 ||
        (cols > 0 && dims[1] != hsize_t(cols)))
      fail(path_, std::string("dataset ") + name + " has the wrong shape" +
                      (cols > 0 ? " (expected [N, " + std::to_string(cols) + "])" : " (expected one-dimensional)"));
    const uint64_t rowBytes = uint64_t(size) * uint64_t(std::max(cols, 1));

    Handle dcpl(checked(H5Dget_create_plist(ds.get())), H5Pclose);
    hsize_t chunk[2] = {0, 0};
    H5D_chunk_index_t index = H5D_CHUNK_IDX_BTREE;
    if (!dcpl.ok() || H5Pget_layout(dcpl.get()) != H5D_CHUNKED || H5Pget_chunk(dcpl.get(), 2, chunk) != rank ||
        chunk[0] == 0 || (cols > 0 && chunk[1] != hsize_t(cols)) || chunk[0] > kMaxChunkBytes / rowBytes)
      fail(path_, std::string("dataset ") + name + " is not stored in chunks as templates are");
    // The HDF5 1.8 chunk index (a version-1 B-tree) has no checksums.
    if (checked(H5Dget_chunk_index_type(ds.get(), &index)) < 0 || index == H5D_CHUNK_IDX_BTREE)
      fail(path_, std::string("dataset ") + name + " uses an HDF5 1.8 chunk index, which templates do not use");
    uint64_t maxBytes = fileSize();
    const int filters = H5Pget_nfilters(dcpl.get());
    if (filters < 0) failHdf5(path_, std::string("cannot read the filters of dataset ") + name);
    for (int i = 0; i < filters; ++i) {
      unsigned flags = 0;
      size_t nValues = 0;
      const H5Z_filter_t id = H5Pget_filter2(dcpl.get(), unsigned(i), &flags, &nValues, nullptr, 0, nullptr, nullptr);
      if (id == H5Z_FILTER_DEFLATE) maxBytes = fileSize() * kMaxDeflateRatio;
      else if (id != H5Z_FILTER_SHUFFLE && id != H5Z_FILTER_FLETCHER32)
        fail(path_, std::string("dataset ") + name + " uses HDF5 filter " + std::to_string(id) +
                        ", which templates do not use");
    }
    if (dims[0] > maxBytes / rowBytes)
      fail(path_, "is damaged: dataset " + std::string(name) + " claims " + std::to_string(dims[0]) +
                      " rows, more than a file of " + std::to_string(fileSize()) + " bytes can hold");
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

  // Rows [first, first + rows) of a dataset of `cols` columns (0: one-dimensional).
  template <class T>
  std::vector<T> readRows(const Handle& ds, hid_t memType, hsize_t first, hsize_t rows, int cols,
                          const char* name) const {
    const hsize_t width = hsize_t(std::max(cols, 1));
    std::vector<T> v(size_t(rows * width));
    if (rows == 0) return v;
    const hsize_t start[2] = {first, 0}, count[2] = {rows, width};
    const int rank = cols > 0 ? 2 : 1;
    Handle file(checked(H5Dget_space(ds.get())), H5Sclose);
    Handle memory(checked(H5Screate_simple(rank, count, nullptr)), H5Sclose);
    if (!file.ok() || !memory.ok() ||
        checked(H5Sselect_hyperslab(file.get(), H5S_SELECT_SET, start, nullptr, count, nullptr)) < 0 ||
        checked(H5Dread(ds.get(), memType, memory.get(), file.get(), H5P_DEFAULT, v.data())) < 0)
      failHdf5(path_, std::string("cannot read rows of dataset ") + name + " (truncated or corrupt?)");
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
  static std::vector<unsigned char> readImage(const std::string& path) {
    std::error_code ec;
    const auto st = fs::status(path, ec);
    if (!fs::exists(st)) fail(path, "does not exist");
    if (!fs::is_regular_file(st)) fail(path, "is not a regular file");
    const int fd = ::open(path.c_str(), O_RDONLY | O_CLOEXEC);
    if (fd < 0) fail(path, std::string("cannot be opened: ") + std::strerror(errno));
    struct Closer {
      int fd;
      ~Closer() { ::close(fd); }
    } closer{fd};
    struct stat sb {};
    if (::fstat(fd, &sb) != 0) fail(path, std::string("cannot be read: ") + std::strerror(errno));
    if (!S_ISREG(sb.st_mode)) fail(path, "is not a regular file");
    std::vector<unsigned char> bytes;
    try {
      bytes.resize(size_t(sb.st_size));
    } catch (const std::exception&) {
      fail(path, "is too large to load (" + std::to_string(sb.st_size) + " bytes)");
    }
    for (size_t done = 0; done < bytes.size();) {
      const ssize_t got = ::pread(fd, bytes.data() + done, bytes.size() - done, off_t(done));
      if (got < 0 && errno == EINTR) continue;
      if (got < 0) fail(path, std::string("cannot be read: ") + std::strerror(errno));
      if (got == 0) fail(path, "became shorter while it was read");
      done += size_t(got);
    }
    return bytes;
  }

  // Checks the bytes (checksum block, superblock, global heap) and opens
  // them with HDF5.
  hid_t open() {
    const unsigned char* p = image_.data();
    const size_t n = image_.size();
    auto hdf5At = [&](size_t at) { return n >= at + 8 && std::memcmp(p + at, kHdf5Signature, 8) == 0; };
    const std::string_view head(reinterpret_cast<const char*>(p), std::min(n, kChecksumMagic.size()));
    if (head == kChecksumMagic) {
      verifyChecksumBlock(p);
    } else if (!hdf5At(0)) {
      if (hdf5At(kChecksumBlockSize)) fail(path_, "is damaged: its checksum block (the first 512 bytes) is unreadable");
      fail(path_, "is not an HDF5 file (no HDF5 signature: wrong kind of file, or corrupt)");
    }
    checkSuperblock();
    if (!checksummed_) checkGlobalHeaps();
    const hid_t f = hdf5::openImage(image_);
    if (f < 0) failHdf5(path_, "cannot be opened as HDF5 (truncated or corrupt?)");
    return f;
  }

  // The checksum block read from the disk, the rest streamed through the
  // CRC, then the file opened by HDF5 and checked to be the one verified
  // (the same inode: a template is replaced by renaming, never rewritten in
  // place).
  hid_t openFromDisk() {
    unsigned char block[kChecksumBlockSize];
    const std::string_view head(reinterpret_cast<const char*>(block), kChecksumMagic.size());
    if (!bytesAt(0, block, kChecksumBlockSize) || head != kChecksumMagic)
      fail(path_, "has no checksum block (written before templates had one): it is read whole, not streamed");
    verifyChecksumBlock(block);
    checkSuperblock();
    Handle fapl(checked(H5Pcreate(H5P_FILE_ACCESS)), H5Pclose);
    if (!fapl.ok() || checked(H5Pset_fapl_sec2(fapl.get())) < 0 ||
        checked(H5Pset_fclose_degree(fapl.get(), H5F_CLOSE_STRONG)) < 0)
      failHdf5(path_, "cannot set up the file access properties");
    const hid_t f = checked(H5Fopen(path_.c_str(), H5F_ACC_RDONLY, fapl.get()));
    if (f < 0) failHdf5(path_, "cannot be opened as HDF5 (truncated or corrupt?)");
    int* handle = nullptr;
    struct stat theirs {};
    if (checked(H5Fget_vfd_handle(f, fapl.get(), reinterpret_cast<void**>(&handle))) < 0 || !handle ||
        ::fstat(*handle, &theirs) != 0 || theirs.st_dev != disk_->dev || theirs.st_ino != disk_->ino) {
      H5Fclose(f);
      fail(path_, "was replaced while it was opened");
    }
    return f;
  }

  // The checksum block at the file's start (its magic already seen) against
  // the rest of the file, which must then start with HDF5's signature.
  void verifyChecksumBlock(const unsigned char* block) {
    uint32_t crc = 0;
    uint64_t length = 0;
    if (fileSize() < kChecksumBlockSize || !parseChecksumBlock(block, &crc, &length))
      fail(path_, "is damaged: its checksum block (the first 512 bytes) is unreadable");
    if (length != fileSize() - kChecksumBlockSize)
      fail(path_, "is truncated or damaged: its checksum block covers " + std::to_string(length) +
                      " bytes after it, the file has " + std::to_string(fileSize() - kChecksumBlockSize));
    const uint32_t actual = crcAfterBlock(length);
    if (actual != crc) {
      char text[96];
      std::snprintf(text, sizeof text, "(CRC-32 %08x, the checksum block says %08x)", unsigned(actual), unsigned(crc));
      fail(path_, std::string("is damaged: its content does not match its checksum ") + text);
    }
    checksummed_ = true;
    base_ = kChecksumBlockSize;
    unsigned char signature[8];
    if (!bytesAt(base_, signature, 8) || std::memcmp(signature, kHdf5Signature, 8) != 0)
      fail(path_, "is damaged: no HDF5 signature after its checksum block");
  }

  // The CRC-32 of the `length` bytes after the checksum block: the image at
  // once, the disk a megabyte at a time.
  uint32_t crcAfterBlock(uint64_t length) const {
    const uint32_t empty = crc32Of(0, nullptr, 0);
    if (!disk_) return crc32Of(empty, image_.data() + kChecksumBlockSize, length);
    std::vector<unsigned char> buf(size_t(1) << 20);
    uint32_t crc = empty;
    for (uint64_t done = 0; done < length;) {
      const size_t n = size_t(std::min<uint64_t>(buf.size(), length - done));
      if (!bytesAt(kChecksumBlockSize + done, buf.data(), n)) fail(path_, "became shorter while it was read");
      crc = crc32Of(crc, buf.data(), n);
      done += n;
    }
    return crc;
  }

  // n bytes at `at` of the file (the image, or the disk): false if it is shorter.
  bool bytesAt(uint64_t at, void* out, size_t n) const {
    if (!disk_) {
      if (at > image_.size() || image_.size() - at < n) return false;
      std::memcpy(out, image_.data() + at, n);
      return true;
    }
    for (size_t done = 0; done < n;) {
      const ssize_t got = ::pread(disk_->fd, static_cast<unsigned char*>(out) + done, n - done, off_t(at + done));
      if (got < 0 && errno == EINTR) continue;
      if (got <= 0) return false;
      done += size_t(got);
    }
    return true;
  }

  // The superblock of the HDF5 1.10 format that writeTemplate writes
  // (version 2 or 3: checksummed; 8-byte addresses and lengths), with the
  // root group's object header where it points.
  void checkSuperblock() const {
    unsigned char h[48];
    const uint64_t n = fileSize() - base_;
    if (n < 48 || !bytesAt(base_, h, 48)) fail(path_, "is truncated: its HDF5 superblock is cut off");
    if (h[8] != 2 && h[8] != 3)
      fail(path_, "is HDF5 but not a FlowClip template, or is damaged (HDF5 superblock version " +
                      std::to_string(h[8]) + "; templates use the HDF5 1.10 format, versions 2 and 3)");
    if (h[9] != 8 || h[10] != 8)
      fail(path_, "is HDF5 but not a FlowClip template, or is damaged (" + std::to_string(h[9]) +
                      "-byte HDF5 addresses, " + std::to_string(h[10]) + "-byte lengths; templates use 8 and 8)");
    if (!objectHeaderAt(le64(h + 36))) fail(path_, "is damaged: its root group has no HDF5 1.10 object header");
  }

  // A version-2 object header (signature OHDR, checksummed) at the HDF5
  // address `addr`: HDF5 1.10 verifies those before parsing them.
  bool objectHeaderAt(uint64_t addr) const {
    const uint64_t n = fileSize() - base_;
    char sig[4];
    return addr < n && n - addr >= 4 && bytesAt(base_ + addr, sig, 4) && std::memcmp(sig, "OHDR", 4) == 0;
  }

  // True if `name` (absolute, each component checked) is a hard link to an
  // object with a version-2 object header; false if it does not exist.
  bool requireObject(const std::string& name) const {
    for (size_t slash = name.find('/', 1);; slash = name.find('/', slash + 1)) {
      const std::string part = name.substr(0, slash);
      const htri_t exists = checked(H5Lexists(file(), part.c_str(), H5P_DEFAULT));
      if (exists < 0) failHdf5(path_, "cannot look up " + part + " (damaged?)");
      if (exists == 0) return false;
      H5L_info_t info{};
      if (checked(H5Lget_info(file(), part.c_str(), &info, H5P_DEFAULT)) < 0 || info.type != H5L_TYPE_HARD)
        fail(path_, part + " is not an object of the file");
      if (!objectHeaderAt(info.u.address))
        fail(path_, "is damaged: " + part + " has no HDF5 1.10 object header");
      if (slash == std::string::npos) return true;
    }
  }

  // HDF5 1.10 walks a global heap collection (where variable-length strings
  // live) without a checksum and trusts its sizes and indices. Checks every
  // collection as HDF5 walks it, plus what writeTemplate's always satisfy:
  // objects 1, 2, 3... in order, each a string (no NUL byte), zero padding,
  // free space last.
  void checkGlobalHeaps() const {
    const unsigned char* h = image_.data() + base_;
    const size_t n = image_.size() - base_;
    static constexpr unsigned char kSignature[5] = {'G', 'C', 'O', 'L', 1};
    for (size_t pos = 0; pos < n;) {
      const void* hit = ::memmem(h + pos, n - pos, kSignature, sizeof kSignature);
      if (!hit) break;
      pos = size_t(static_cast<const unsigned char*>(hit) - h);
      const unsigned char* c = h + pos;
      auto bad = [&](const std::string& what) {
        fail(path_, "is damaged: the global heap (string storage) at byte " + std::to_string(base_ + pos) + " " + what);
      };
      if (n - pos < 16) bad("is cut off");
      const uint64_t size = le64(c + 8);
      if (size < 4096 || size > n - pos) bad("has an impossible size (" + std::to_string(size) + " bytes)");
      uint64_t at = 16;
      for (unsigned next = 1; size - at >= 16; ++next) {
        const unsigned index = le16(c + at);
        const uint64_t objectSize = le64(c + at + 8);
        if (index == 0) {  // the free space: the rest of the collection
          if (objectSize != size - at) bad("has free space of the wrong size");
          break;
        }
        if (index != next) bad("has object " + std::to_string(index) + " where " + std::to_string(next) + " belongs");
        const uint64_t room = size - at - 16;
        if (objectSize > room || (objectSize + 7) / 8 * 8 > room)
          bad("has object " + std::to_string(index) + " larger than the heap");
        const unsigned char* data = c + at + 16;
        const uint64_t padded = (objectSize + 7) / 8 * 8;
        if (std::memchr(data, 0, objectSize)) bad("has object " + std::to_string(index) + " with a NUL byte");
        for (uint64_t k = objectSize; k < padded; ++k)
          if (data[k] != 0) bad("has object " + std::to_string(index) + " with non-zero padding");
        at += 16 + padded;
      }
      pos += 1;
    }
  }

  // A plain integer (any size, all bits used) or IEEE float type: what
  // templates store and HDF5 converts without surprises.
  static bool plainNumber(hid_t type, bool integerOnly) {
    const H5T_class_t cls = H5Tget_class(type);
    if (cls == H5T_INTEGER) {
      const size_t size = H5Tget_size(type);
      return (size == 1 || size == 2 || size == 4 || size == 8) && H5Tget_precision(type) == 8 * size &&
             H5Tget_offset(type) == 0;
    }
    if (cls != H5T_FLOAT || integerOnly) return false;
    for (hid_t t : {H5T_IEEE_F32LE, H5T_IEEE_F32BE, H5T_IEEE_F64LE, H5T_IEEE_F64BE})
      if (H5Tequal(type, t) > 0) return true;
    return false;
  }

  std::string path_;
  // The file opened for reading from the disk, and what it was when opened.
  struct Disk {
    int fd = -1;
    uint64_t size = 0;
    dev_t dev{};
    ino_t ino{};
    ~Disk() {
      if (fd >= 0) ::close(fd);
    }
  };
  static std::unique_ptr<Disk> openDisk(const std::string& path) {
    std::error_code ec;
    const auto st = fs::status(path, ec);
    if (!fs::exists(st)) fail(path, "does not exist");
    if (!fs::is_regular_file(st)) fail(path, "is not a regular file");
    auto d = std::make_unique<Disk>();
    d->fd = ::open(path.c_str(), O_RDONLY | O_CLOEXEC);
    if (d->fd < 0) fail(path, std::string("cannot be opened: ") + std::strerror(errno));
    struct stat sb {};
    if (::fstat(d->fd, &sb) != 0) fail(path, std::string("cannot be read: ") + std::strerror(errno));
    if (!S_ISREG(sb.st_mode)) fail(path, "is not a regular file");
    d->size = uint64_t(sb.st_size), d->dev = sb.st_dev, d->ino = sb.st_ino;
    return d;
  }

  std::vector<unsigned char> image_;  // the whole file; HDF5 reads it in place
  std::unique_ptr<Disk> disk_;        // or the file on the disk (FromDisk)
  bool checksummed_ = false;
  size_t base_ = 0;  // where the HDF5 file starts in image_ (after the checksum block)
  Handle file_;      // declared last: closed before image_ goes
};

TemplateHeader readHeader(const Reader& r) {
  const std::string& path = r.path();
  if (!r.hasAttr("format")) fail(path, "is HDF5 but not a FlowClip template (no 'format' attribute)");
  const std::string format = r.string("format");
  if (format != kFormat)
    fail(path, "is HDF5 but not a FlowClip template (format is " + excerpt(format) + ", expected '" + kFormat + "')");
  const int64_t version = r.integer("format_version");
  if (version != kTemplateFormatVersion)
    fail(path, "has format_version " + std::to_string(version) + "; this program reads format_version " +
                   std::to_string(kTemplateFormatVersion));
  TemplateHeader h;
  const int64_t dim = r.integer("dimension");
  if (dim != 2 && dim != 3) fail(path, "has dimension " + std::to_string(dim) + " (must be 2 or 3)");
  h.dimension = int(dim);
  h.name = r.string("name");
  if (!std::regex_match(h.name, kNamePattern)) fail(path, "has the name " + excerpt(h.name) + ", not [A-Za-z0-9_-]{1,64}");
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
  if (!std::regex_match(h.name, kNamePattern)) invalid("template name '" + h.name + "' is not [A-Za-z0-9_-]{1,64}");
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

  // Written under the hidden stagingPath(path), which recoverPublishing()
  // deletes after a crash, then published (io/staged_files.h).
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
    // Room for the checksum block, written once HDF5 has closed the file.
    Handle fcpl(checked(H5Pcreate(H5P_FILE_CREATE)), H5Pclose);
    if (!fcpl.ok() || checked(H5Pset_userblock(fcpl.get(), kChecksumBlockSize)) < 0)
      abandon("cannot set up the file creation properties", true);
    // EXCL: never truncate a file we did not create.
    Handle file(checked(H5Fcreate(tmp.c_str(), H5F_ACC_EXCL, fcpl.get(), fapl.get())), H5Fclose);
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
    if (checked(H5Fflush(fid, H5F_SCOPE_LOCAL)) < 0 || checked(H5Fclose(file.release())) < 0)
      abandon("cannot write the temporary file '" + tmp + "'", true);
  }
  if (const std::string error = stampChecksum(tmp); !error.empty())
    abandon("cannot write the checksum of '" + tmp + "': " + error, false);
  try {
    publishStaged(tmp, path, /*replace=*/true);
  } catch (const PublishError& e) {
    abandon(e.what(), false);
  }
}

// A file with a checksum block is read from the disk, verified as it streams
// by: its bytes need not be held to read its header and index.
bool startsWithChecksumBlock(const std::string& path) {
  char head[kChecksumMagic.size()];
  const int fd = ::open(path.c_str(), O_RDONLY | O_CLOEXEC);
  if (fd < 0) return false;
  const ssize_t got = ::pread(fd, head, sizeof head, 0);
  ::close(fd);
  return got == ssize_t(sizeof head) && std::string_view(head, sizeof head) == kChecksumMagic;
}

TemplateHeader readTemplateHeader(const std::string& path) {
  hdf5::Quiet quiet;
  if (startsWithChecksumBlock(path)) return readHeader(Reader(path, Reader::FromDisk{}));
  Reader r(path);
  return readHeader(r);
}

namespace {

// How a file stores its particles (its header's encodings and the tables
// they need), read and checked once.
template <int D>
struct Layout {
  TemplateHeader header;
  size_t frames = 0;
  hsize_t rows = 0;
  std::vector<uint64_t> offset;  // frame f: rows offset[f]..offset[f + 1]
  std::vector<double> velScale;
  bool quantized = false, massIndexed = false;
  std::vector<double> origin, step, massTable;
  std::optional<Handle> phase, velocity, position, mass;  // mass: /particles/mass_index or /particles/mass
};

template <int D>
Layout<D> readLayout(const Reader& r) {
  const std::string& path = r.path();
  Layout<D> l;
  l.header = readHeader(r);
  if (l.header.dimension != D)
    fail(path, "is a " + std::to_string(l.header.dimension) + "D template, expected a " + std::to_string(D) +
                   "D one");
  l.frames = size_t(r.integer("frame_count"));
  const std::string posEnc = r.string("position_encoding");
  const std::string velEnc = r.string("velocity_encoding");
  const std::string massEnc = r.string("mass_encoding");
  if (posEnc != "uint16" && posEnc != "float32") fail(path, "unknown position_encoding '" + posEnc + "'");
  if (velEnc != "int16_frame_scale") fail(path, "unknown velocity_encoding '" + velEnc + "'");
  if (massEnc != "table" && massEnc != "float64") fail(path, "unknown mass_encoding '" + massEnc + "'");
  l.quantized = posEnc == "uint16";
  l.massIndexed = massEnc == "table";

  const hsize_t N = l.rows = r.particleRows();
  l.offset = r.offsets(l.frames, N);
  auto checkRows = [&](const char* name, hsize_t rows) {
    if (rows != N)
      fail(path, std::string(name) + " has " + std::to_string(rows) + " rows, /particles/phase has " +
                     std::to_string(N));
  };
  hsize_t rows = 0;
  l.phase.emplace(r.openDataset("/particles/phase", H5T_INTEGER, 1, H5T_SGN_NONE, 0, &rows));
  Handle scaleDs = r.openDataset("/frames/velocity_scale", H5T_FLOAT, 8, 0, 0, &rows);
  if (rows != l.frames)
    fail(path, "/frames/velocity_scale has " + std::to_string(rows) + " entries, expected frame_count");
  l.velScale = r.read<double>(scaleDs, H5T_NATIVE_DOUBLE, l.frames, "/frames/velocity_scale");
  for (size_t f = 0; f < l.frames; ++f)
    if (!finite(l.velScale[f]) || l.velScale[f] < 0)
      fail(path, "/frames/velocity_scale of frame " + std::to_string(f) + " is negative or not finite");
  l.velocity.emplace(r.openDataset("/particles/velocity", H5T_INTEGER, 2, H5T_SGN_2, D, &rows));
  checkRows("/particles/velocity", rows);
  if (l.quantized) {
    l.origin = r.doubles("position_origin", D);
    l.step = r.doubles("position_step", D);
    for (double s : l.step)
      if (!(s > 0)) fail(path, "attribute 'position_step' must be positive");
    l.position.emplace(r.openDataset("/particles/position", H5T_INTEGER, 2, H5T_SGN_NONE, D, &rows));
  } else {
    l.position.emplace(r.openDataset("/particles/position", H5T_FLOAT, 4, 0, D, &rows));
  }
  checkRows("/particles/position", rows);
  if (l.massIndexed) {
    l.massTable = r.doubles("mass_table", -1, 256);
    if (l.massTable.empty() && N > 0) fail(path, "attribute 'mass_table' is empty");
    l.mass.emplace(r.openDataset("/particles/mass_index", H5T_INTEGER, 1, H5T_SGN_NONE, 0, &rows));
    checkRows("/particles/mass_index", rows);
  } else {
    l.mass.emplace(r.openDataset("/particles/mass", H5T_FLOAT, 8, 0, 0, &rows));
    checkRows("/particles/mass", rows);
  }
  return l;
}

// Rows [first, first + n) of the particle datasets, checked and decoded
// into frames: every frame whose rows they hold (whole file), or one.
template <int D>
void decodeRows(const Reader& r, const Layout<D>& l, hsize_t first, hsize_t n, size_t frameFirst, size_t frameLast,
                std::vector<TemplateFrame<D>>& out) {
  const std::string& path = r.path();
  const auto phase = r.readRows<uint8_t>(*l.phase, H5T_NATIVE_UINT8, first, n, 0, "/particles/phase");
  const auto velQ = r.readRows<int16_t>(*l.velocity, H5T_NATIVE_INT16, first, n, D, "/particles/velocity");
  std::vector<uint16_t> posQ;
  std::vector<float> posF;
  if (l.quantized) {
    posQ = r.readRows<uint16_t>(*l.position, H5T_NATIVE_UINT16, first, n, D, "/particles/position");
  } else {
    posF = r.readRows<float>(*l.position, H5T_NATIVE_FLOAT, first, n, D, "/particles/position");
    for (size_t i = 0; i < posF.size(); ++i)
      if (!std::isfinite(posF[i]))
        fail(path, "/particles/position row " + std::to_string(first + i / D) + " is not finite");
  }
  std::vector<double> mass;
  std::vector<uint8_t> massIdx;
  if (l.massIndexed) {
    massIdx = r.readRows<uint8_t>(*l.mass, H5T_NATIVE_UINT8, first, n, 0, "/particles/mass_index");
    for (size_t i = 0; i < n; ++i)
      if (massIdx[i] >= l.massTable.size())
        fail(path, "/particles/mass_index row " + std::to_string(first + i) + " is outside mass_table");
  } else {
    mass = r.readRows<double>(*l.mass, H5T_NATIVE_DOUBLE, first, n, 0, "/particles/mass");
    for (size_t i = 0; i < n; ++i)
      if (!finite(mass[i])) fail(path, "/particles/mass row " + std::to_string(first + i) + " is not finite");
  }
  for (size_t f = frameFirst; f < frameLast; ++f) {
    TemplateFrame<D>& fr = out[f - frameFirst];
    const size_t a = size_t(l.offset[f] - first), count = size_t(l.offset[f + 1] - l.offset[f]);
    fr.x.resize(count);
    fr.v.resize(count);
    fr.mass.resize(count);
    fr.phase.assign(phase.begin() + a, phase.begin() + a + count);
    for (size_t k = 0; k < count; ++k) {
      const size_t row = a + k;
      for (int d = 0; d < D; ++d) {
        fr.x[k][d] = l.quantized ? Real(l.origin[d] + posQ[row * D + d] * l.step[d]) : Real(posF[row * D + d]);
        fr.v[k][d] = Real(velQ[row * D + d] * l.velScale[f]);
      }
      fr.mass[k] = Real(l.massIndexed ? l.massTable[massIdx[row]] : mass[row]);
    }
  }
}

}  // namespace

template <int D>
Template<D> readTemplate(const std::string& path) {
  hdf5::Quiet quiet;
  Reader r(path);
  const Layout<D> l = readLayout<D>(r);
  Template<D> tpl;
  tpl.header = l.header;
  tpl.frames.resize(l.frames);
  decodeRows<D>(r, l, 0, l.rows, 0, l.frames, tpl.frames);
  return tpl;
}

template <int D>
struct TemplateStream<D>::Impl {
  Reader reader;
  Layout<D> layout;
  explicit Impl(const std::string& path) : reader(path, Reader::FromDisk{}), layout(readLayout<D>(reader)) {}
};

template <int D>
TemplateStream<D>::TemplateStream(const std::string& path) {
  hdf5::Quiet quiet;
  impl_ = std::make_unique<Impl>(path);
}
template <int D>
TemplateStream<D>::~TemplateStream() = default;

template <int D>
const TemplateHeader& TemplateStream<D>::header() const {
  return impl_->layout.header;
}
template <int D>
size_t TemplateStream<D>::frameCount() const {
  return impl_->layout.frames;
}
template <int D>
size_t TemplateStream<D>::frameParticles(size_t f) const {
  return size_t(impl_->layout.offset.at(f + 1) - impl_->layout.offset[f]);
}
template <int D>
uint64_t TemplateStream<D>::particleFrames() const {
  return impl_->layout.rows;
}
template <int D>
uint64_t TemplateStream<D>::bytesOnDisk() const {
  return impl_->reader.fileSize();
}

template <int D>
TemplateFrame<D> TemplateStream<D>::readFrame(size_t f) const {
  const Layout<D>& l = impl_->layout;
  if (f >= l.frames)
    throw TemplateError(impl_->reader.path() + ": frame " + std::to_string(f) + " of " +
                        std::to_string(l.frames) + " asked for");
  hdf5::Quiet quiet;
  std::vector<TemplateFrame<D>> one(1);
  decodeRows<D>(impl_->reader, l, l.offset[f], l.offset[f + 1] - l.offset[f], f, f + 1, one);
  return std::move(one[0]);
}

TemplateFileStats templateFileStats(const std::string& path) {
  hdf5::Quiet quiet;
  const Reader r = startsWithChecksumBlock(path) ? Reader(path, Reader::FromDisk{}) : Reader(path);
  TemplateFileStats s;
  s.header = readHeader(r);
  s.frames = size_t(r.integer("frame_count"));
  const hsize_t N = r.particleRows();
  const auto off = r.offsets(s.frames, N);
  for (size_t f = 0; f < s.frames; ++f) {
    const size_t n = off[f + 1] - off[f];
    s.minParticles = f == 0 ? n : std::min(s.minParticles, n);
    s.maxParticles = std::max(s.maxParticles, n);
  }
  s.avgParticles = s.frames ? double(N) / double(s.frames) : 0.0;
  s.bytesOnDisk = r.fileSize();
  s.checksummed = r.checksummed();
  s.bytesPerParticleFrame = N ? double(s.bytesOnDisk) / double(N) : 0.0;
  return s;
}

template void writeTemplate<2>(const std::string&, const Template<2>&);
template void writeTemplate<3>(const std::string&, const Template<3>&);
template Template<2> readTemplate<2>(const std::string&);
template Template<3> readTemplate<3>(const std::string&);
template class TemplateStream<2>;
template class TemplateStream<3>;

}  // namespace fc
