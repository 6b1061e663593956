#include "io/frame_export.h"

#include "io/hdf5_util.h"
#include "io/staged_files.h"

#include <hdf5.h>
#include <omp.h>
#include <zlib.h>

#include <fcntl.h>
#include <sys/mman.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <cstdio>
#include <cstring>
#include <exception>
#include <filesystem>
#include <iostream>
#include <stdexcept>
#include <system_error>
#include <type_traits>

namespace fc {

static_assert(std::is_same_v<hid_t, int64_t>, "frame_export.h stores hid_t as int64_t");

namespace {

using hdf5::checked;
using hdf5::Handle;
using hdf5::writeArray;
using hdf5::writeScalar;
using hdf5::writeString;
using hdf5::writeStrings;

// Rows per chunk of the particle datasets (the contract says ~64k rows) and
// of the small per-frame tables.
constexpr hsize_t kParticleChunkRows = 65536;
constexpr hsize_t kFrameChunkRows = 4096;
// Deflate level: level 2 saves under 1% of the file size over level 1 on
// particle data and costs ~10% more time (see docs/export-format.md).
constexpr int kDeflateLevel = 1;
// Completed particle chunks are compressed in parallel in batches of at most
// this many uncompressed bytes, which bounds the exporter's memory.
constexpr size_t kMaxBatchBytes = size_t(64) << 20;

// HDF5's shuffle filter (byte planes: byte b of element i goes to
// b * count + i) followed by its deflate filter (zlib compress2), on one
// whole chunk. `shuffled` is scratch space of the chunk's size.
int packChunk(const std::vector<unsigned char>& raw, size_t elemSize, std::vector<unsigned char>& shuffled,
              std::vector<unsigned char>& out) {
  const unsigned char* src = raw.data();
  if (elemSize > 1) {
    const size_t count = raw.size() / elemSize;
    for (size_t b = 0; b < elemSize; ++b) {
      unsigned char* dst = shuffled.data() + b * count;
      for (size_t i = 0; i < count; ++i) dst[i] = raw[i * elemSize + b];
    }
    src = shuffled.data();
  }
  uLongf len = uLongf(out.size());
  const int rc = compress2(out.data(), &len, src, uLong(raw.size()), kDeflateLevel);
  out.resize(len);
  return rc;
}

// Bytes per element of a particle dataset (the shuffle filter's unit).
size_t elementSize(int ds) { return ds == 4 || ds == 5 ? 1 : 4; }  // phase, kind: uint8

const char* datasetName(int ds) {
  static const char* names[] = {"/particles/position", "/particles/velocity", "/particles/density",
                                "/particles/pressure", "/particles/phase",    "/particles/kind",
                                "/particles/id",       "/frames/index",       "/frames/time",
                                "/frames/offset",      "/frames/count"};
  return names[ds];
}

}  // namespace

template <int D>
FrameExporter<D>::FrameExporter(const std::string& path, const ExportHeader& header)
    : path_(path), tempPath_(stagingPath(path)),
      uncaughtAtCreation_(std::uncaught_exceptions()) {
  for (auto& d : datasets_) d = -1;
  auto invalid = [&](const std::string& what) {
    throw std::runtime_error("cannot export frames to '" + path_ + "': " + what);
  };
  if (header.dimension != D)
    invalid("header dimension " + std::to_string(header.dimension) + " does not match the simulation's " +
            std::to_string(D));
  if (header.domainMin.size() != size_t(D) || header.domainMax.size() != size_t(D))
    invalid("domain min/max must have " + std::to_string(D) + " values");
  if (header.phases.size() > 256) invalid("more than 256 phases do not fit the uint8 phase column");
  {
    // The leftovers of an export killed earlier in this directory go first.
    const std::filesystem::path dir = std::filesystem::path(path_).parent_path();
    recoverPublishing(dir.empty() ? "." : dir.string());
  }

  hdf5::Quiet quiet;
  {
    // sec2 explicitly: discardFile() relies on its handle being a POSIX fd.
    Handle fapl(checked(H5Pcreate(H5P_FILE_ACCESS)), H5Pclose);
    if (!fapl.ok() || checked(H5Pset_fapl_sec2(fapl.get())) < 0 ||
        checked(H5Pset_fclose_degree(fapl.get(), H5F_CLOSE_STRONG)) < 0)
      fail("cannot set up the file access properties");
    file_ = checked(H5Fcreate(tempPath_.c_str(), H5F_ACC_TRUNC, H5P_DEFAULT, fapl.get()));
  }
  if (file_ < 0) fail("cannot create the temporary file '" + tempPath_ + "'");
  open_ = true;

  // Root attributes.
  const int formatVersion = 1;
  const int dimension = D;
  std::vector<std::string> phaseNames;
  std::vector<double> restDensity;
  for (auto& ph : header.phases) {
    phaseNames.push_back(ph.name);
    restDensity.push_back(double(ph.restDensity));
  }
  const bool attrsOk =
      writeString(file_, "format", "flowclip-frames") &&
      writeScalar(file_, "format_version", H5T_STD_I32LE, H5T_NATIVE_INT, &formatVersion) &&
      writeScalar(file_, "dimension", H5T_STD_I32LE, H5T_NATIVE_INT, &dimension) &&
      writeString(file_, "scene", header.sceneName) &&
      writeScalar(file_, "particle_radius", H5T_IEEE_F64LE, H5T_NATIVE_DOUBLE, &header.particleRadius) &&
      writeScalar(file_, "frame_rate", H5T_IEEE_F64LE, H5T_NATIVE_DOUBLE, &header.frameRate) &&
      writeArray(file_, "domain_min", H5T_IEEE_F64LE, H5T_NATIVE_DOUBLE, D, header.domainMin.data()) &&
      writeArray(file_, "domain_max", H5T_IEEE_F64LE, H5T_NATIVE_DOUBLE, D, header.domainMax.data()) &&
      writeString(file_, "created_by", header.createdBy) && writeStrings(file_, "phase_names", phaseNames) &&
      writeArray(file_, "phase_rest_density", H5T_IEEE_F64LE, H5T_NATIVE_DOUBLE, restDensity.size(),
                 restDensity.data()) &&
      (header.source.empty() || writeString(file_, "source", header.source));
  if (!attrsOk) fail("cannot write the header attributes");

  {
    Handle frames(checked(H5Gcreate2(file_, "frames", H5P_DEFAULT, H5P_DEFAULT, H5P_DEFAULT)), H5Gclose);
    Handle particles(checked(H5Gcreate2(file_, "particles", H5P_DEFAULT, H5P_DEFAULT, H5P_DEFAULT)), H5Gclose);
    if (!frames.ok() || !particles.ok()) fail("cannot create the /frames and /particles groups");
  }
  struct Spec {
    Ds ds;
    hid_t type;
    int cols;
    hsize_t chunkRows;
  };
  const Spec specs[] = {
      {Position, H5T_IEEE_F32LE, D, kParticleChunkRows},  {Velocity, H5T_IEEE_F32LE, D, kParticleChunkRows},
      {Density, H5T_IEEE_F32LE, 0, kParticleChunkRows},   {Pressure, H5T_IEEE_F32LE, 0, kParticleChunkRows},
      {PhaseDs, H5T_STD_U8LE, 0, kParticleChunkRows},     {Kind, H5T_STD_U8LE, 0, kParticleChunkRows},
      {Id, H5T_STD_U32LE, 0, kParticleChunkRows},         {FrameIndex, H5T_STD_U32LE, 0, kFrameChunkRows},
      {FrameTime, H5T_IEEE_F64LE, 0, kFrameChunkRows},    {FrameOffset, H5T_STD_U64LE, 0, kFrameChunkRows},
      {FrameCount, H5T_STD_U32LE, 0, kFrameChunkRows},
  };
  // Empty; the filter pipeline is the one packChunk() reproduces (chunks
  // written with H5Dwrite_chunk declare it applied).
  for (const Spec& s : specs) {
    if (!header.solverColumns && (s.ds == Density || s.ds == Pressure || s.ds == Id)) continue;
    datasets_[s.ds] =
        hdf5::createDataset(file_, datasetName(s.ds), s.type, 0, s.cols, s.chunkRows, unsigned(kDeflateLevel));
    if (datasets_[s.ds] < 0) fail(std::string("cannot create ") + datasetName(s.ds));
  }
  const uint64_t zero = 0;
  append(FrameOffset, &zero, H5T_NATIVE_UINT64, 1);
}

template <int D>
FrameExporter<D>::~FrameExporter() {
  if (!open_) return;
  if (std::uncaught_exceptions() > uncaughtAtCreation_) {
    abort();  // the run failed: never publish its partial output
    return;
  }
  try {
    close();
  } catch (const std::exception& e) {
    std::cerr << "flowclip: " << e.what() << std::endl;
  } catch (...) {
  }
}

// HDF5 1.10 has no "close without flushing". After a write error (disk full)
// the flush in H5Fclose fails again, and a file whose close failed is left
// half-destroyed in the library, which then crashes when it retries at exit.
// So before closing a file we are going to delete anyway, point its file
// descriptor at an anonymous in-memory file: the flush succeeds, the disk
// space of the unlinked temporary file is freed, nothing reaches the disk.
template <int D>
void FrameExporter<D>::discardFile() noexcept {
  if (file_ < 0) return;
  void* handle = nullptr;
  if (H5Fget_vfd_handle(file_, H5P_DEFAULT, &handle) < 0 || handle == nullptr) return;
  const int fd = *static_cast<int*>(handle);
  const int mem = ::memfd_create("flowclip-discarded-export", MFD_CLOEXEC);
  if (mem < 0) return;
  if (::dup3(mem, fd, O_CLOEXEC) < 0) {
    ::close(mem);
    return;
  }
  ::close(mem);
}

template <int D>
void FrameExporter<D>::releaseHandles() noexcept {
  for (auto& d : datasets_) {
    if (d >= 0) H5Dclose(d);
    d = -1;
  }
  if (file_ >= 0) H5Fclose(file_);
  file_ = -1;
  ready_.clear();
  for (auto& p : pending_) p = PendingChunk{};
}

template <int D>
void FrameExporter<D>::fail(const std::string& what) {
  const std::string detail = hdf5::takeError();
  discardFile();
  releaseHandles();
  // Only ever called after our H5Fcreate(TRUNC) of this exact name, so a
  // regular file there is ours (possibly partly written by a failed create).
  std::error_code ec;
  if (std::filesystem::is_regular_file(std::filesystem::symlink_status(tempPath_, ec))) std::remove(tempPath_.c_str());
  open_ = false;
  throw std::runtime_error("cannot export frames to '" + path_ + "': " + what +
                           (detail.empty() ? std::string() : " (HDF5: " + detail + ")"));
}

template <int D>
void FrameExporter<D>::append(Ds ds, const void* data, int64_t memType, uint64_t rows) {
  // The per-frame tables, through HDF5's own chunk cache and filters.
  const hsize_t start = sizes_[ds];
  const hsize_t count = rows;
  const hsize_t extent = sizes_[ds] + rows;
  const hid_t dset = datasets_[ds];
  bool ok = checked(H5Dset_extent(dset, &extent)) >= 0;
  if (ok) {
    Handle fileSpace(checked(H5Dget_space(dset)), H5Sclose);
    Handle memSpace(checked(H5Screate_simple(1, &count, nullptr)), H5Sclose);
    ok = fileSpace.ok() && memSpace.ok() &&
         checked(H5Sselect_hyperslab(fileSpace.get(), H5S_SELECT_SET, &start, nullptr, &count, nullptr)) >= 0 &&
         checked(H5Dwrite(dset, memType, memSpace.get(), fileSpace.get(), H5P_DEFAULT, data)) >= 0;
  }
  if (!ok) fail(std::string("cannot write ") + datasetName(ds));
  sizes_[ds] += rows;
}

template <int D>
void FrameExporter<D>::stage(Ds ds, const void* rowsData, uint64_t rows) {
  const size_t rowBytes = elementSize(ds) * (ds == Position || ds == Velocity ? D : 1);
  const auto* src = static_cast<const unsigned char*>(rowsData);
  PendingChunk& p = pending_[ds];
  while (rows > 0) {
    if (p.bytes.empty()) p.bytes.resize(kParticleChunkRows * rowBytes);  // zeroed: the padding of a last chunk
    const uint64_t take = std::min<uint64_t>(rows, kParticleChunkRows - p.rows);
    std::memcpy(p.bytes.data() + p.rows * rowBytes, src, take * rowBytes);
    p.rows += take;
    src += take * rowBytes;
    rows -= take;
    if (p.rows == kParticleChunkRows) {
      ready_.push_back(ReadyChunk{ds, p.index++, std::move(p.bytes)});
      p.bytes = {};
      p.rows = 0;
    }
  }
  size_t batch = 0;
  for (auto& r : ready_) batch += r.bytes.size();
  if (batch >= kMaxBatchBytes) writeReadyChunks();
}

template <int D>
void FrameExporter<D>::writeReadyChunks() {
  const long count = long(ready_.size());
  if (count == 0) return;
  // All allocation before the parallel region: nothing in it can throw.
  size_t largest = 0;
  std::vector<std::vector<unsigned char>> packed(count);
  for (long k = 0; k < count; ++k) {
    largest = std::max(largest, ready_[k].bytes.size());
    packed[k].resize(compressBound(uLong(ready_[k].bytes.size())));
  }
  const int threads = std::max(1, std::min(omp_get_max_threads(), int(count)));
  std::vector<std::vector<unsigned char>> shuffled(threads, std::vector<unsigned char>(largest));
  std::vector<int> status(count, Z_OK);
#pragma omp parallel for num_threads(threads) schedule(dynamic, 1)
  for (long k = 0; k < count; ++k)
    status[k] = packChunk(ready_[k].bytes, elementSize(ready_[k].ds), shuffled[omp_get_thread_num()], packed[k]);

  for (long k = 0; k < count; ++k) {
    const int ds = ready_[k].ds;
    if (status[k] != Z_OK)
      fail(std::string("cannot compress a chunk of ") + datasetName(ds) + " (zlib error " + std::to_string(status[k]) +
           ")");
    const hsize_t offset[2] = {ready_[k].index * kParticleChunkRows, 0};
    if (checked(H5Dwrite_chunk(datasets_[ds], H5P_DEFAULT, 0, offset, packed[k].size(), packed[k].data())) < 0)
      fail(std::string("cannot write ") + datasetName(ds));
  }
  ready_.clear();
}

template <int D>
void FrameExporter<D>::checkFrame(int frameIndex, size_t n) {
  if (!open_) throw std::runtime_error("cannot export frames to '" + path_ + "': the exporter is closed");
  if (frameIndex < 0)
    throw std::runtime_error("cannot export frames to '" + path_ + "': negative frame index " +
                             std::to_string(frameIndex));
  if (n > UINT32_MAX)
    throw std::runtime_error("cannot export frames to '" + path_ + "': more than 2^32 particles in one frame");
}

// Extents first: every chunk written afterwards lies inside the dataset.
template <int D>
void FrameExporter<D>::extendParticleDatasets(uint64_t end) {
  for (int ds = 0; ds < NumParticleDs; ++ds) {
    if (datasets_[ds] < 0) continue;  // left out by the header
    const hsize_t extent[2] = {end, hsize_t(D)};
    if (checked(H5Dset_extent(datasets_[ds], extent)) < 0) fail(std::string("cannot extend ") + datasetName(ds));
  }
}

template <int D>
void FrameExporter<D>::finishFrame(int frameIndex, double time, size_t n) {
  const uint64_t end = rows_ + n;
  const uint32_t index = uint32_t(frameIndex);
  const uint32_t count = uint32_t(n);
  append(FrameIndex, &index, H5T_NATIVE_UINT32, 1);
  append(FrameTime, &time, H5T_NATIVE_DOUBLE, 1);
  append(FrameOffset, &end, H5T_NATIVE_UINT64, 1);
  append(FrameCount, &count, H5T_NATIVE_UINT32, 1);
  rows_ = end;
  ++frames_;
}

template <int D>
void FrameExporter<D>::writeFrame(int frameIndex, double time, const FluidParticles<D>& fluid) {
  static_assert(sizeof(Vec<D>) == D * sizeof(Real), "Vec<D> must be D packed Reals");
  static_assert(PhaseDs == 4 && Kind == 5, "elementSize() knows the uint8 columns by number");
  if (!open_) throw std::runtime_error("cannot export frames to '" + path_ + "': the exporter is closed");
  const size_t n = fluid.x.size();
  if (fluid.v.size() != n || fluid.density.size() != n || fluid.meanPressure.size() != n || fluid.phase.size() != n ||
      fluid.kind.size() != n || fluid.id.size() != n)
    throw std::runtime_error("cannot export frames to '" + path_ + "': frame " + std::to_string(frameIndex) +
                             " has particle arrays of different lengths");
  checkFrame(frameIndex, n);

  hdf5::Quiet quiet;
  if (n > 0) {
    extendParticleDatasets(rows_ + n);
    auto asFloat = [&](const auto* p, size_t count) -> const float* {  // generic: discards a branch
      if constexpr (std::is_same_v<std::remove_cv_t<std::remove_pointer_t<decltype(p)>>, float>) {
        return p;
      } else {
        scratch_.assign(p, p + count);
        return scratch_.data();
      }
    };
    stage(Position, asFloat(fluid.x.data()->data(), n * D), n);
    stage(Velocity, asFloat(fluid.v.data()->data(), n * D), n);
    if (datasets_[Density] >= 0) stage(Density, asFloat(fluid.density.data(), n), n);
    if (datasets_[Pressure] >= 0) stage(Pressure, asFloat(fluid.meanPressure.data(), n), n);
    stage(PhaseDs, fluid.phase.data(), n);
    stage(Kind, fluid.kind.data(), n);
    if (datasets_[Id] >= 0) stage(Id, fluid.id.data(), n);
    writeReadyChunks();
  }
  finishFrame(frameIndex, time, n);
}

template <int D>
void FrameExporter<D>::writeFrame(int frameIndex, double time, const ExportColumns& c) {
  const size_t n = c.count;
  checkFrame(frameIndex, n);
  if (n > 0) {
    const bool solver = datasets_[Density] >= 0;
    if (!c.position || !c.velocity || !c.phase || !c.kind ||
        (solver && (!c.density || !c.pressure || !c.id)))
      throw std::runtime_error("cannot export frames to '" + path_ + "': frame " + std::to_string(frameIndex) +
                               " lacks a column the file holds");
  }
  hdf5::Quiet quiet;
  if (n > 0) {
    extendParticleDatasets(rows_ + n);
    stage(Position, c.position, n);
    stage(Velocity, c.velocity, n);
    if (datasets_[Density] >= 0) stage(Density, c.density, n);
    if (datasets_[Pressure] >= 0) stage(Pressure, c.pressure, n);
    stage(PhaseDs, c.phase, n);
    stage(Kind, c.kind, n);
    if (datasets_[Id] >= 0) stage(Id, c.id, n);
    writeReadyChunks();
  }
  finishFrame(frameIndex, time, n);
}

template <int D>
void FrameExporter<D>::close() {
  if (!open_) return;
  hdf5::Quiet quiet;
  for (int ds = 0; ds < NumParticleDs; ++ds) {
    PendingChunk& p = pending_[ds];
    if (p.rows > 0) ready_.push_back(ReadyChunk{ds, p.index++, std::move(p.bytes)});
    p = PendingChunk{};
  }
  writeReadyChunks();
  // Flush first: a failed flush leaves the file in a state fail() can still
  // discard cleanly, and the closes that follow have little left to write.
  if (checked(H5Fflush(file_, H5F_SCOPE_LOCAL)) < 0) fail("cannot write the temporary file '" + tempPath_ + "'");
  for (int ds = 0; ds < NumDatasets; ++ds) {
    if (datasets_[ds] < 0) continue;  // left out by the header
    if (checked(H5Dclose(datasets_[ds])) < 0) fail(std::string("cannot finish ") + datasetName(ds));
    datasets_[ds] = -1;
  }
  if (checked(H5Fclose(file_)) < 0) fail("cannot finish the temporary file '" + tempPath_ + "'");
  file_ = -1;
  // fsynced before the name points at it: a crash cannot leave a truncated file under <path>.
  try {
    publishStaged(tempPath_, path_, /*replace=*/true);
  } catch (const PublishError& e) {
    fail(e.what());
  }
  open_ = false;
}

template <int D>
void FrameExporter<D>::abort() noexcept {
  if (!open_) return;
  hdf5::Quiet quiet;
  discardFile();
  releaseHandles();
  std::remove(tempPath_.c_str());
  open_ = false;
}

FC_INSTANTIATE_DIMS(FrameExporter)

}  // namespace fc
