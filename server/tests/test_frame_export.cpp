// FrameExporter: round trip through HDF5, atomic publication, error paths.
#include "io/frame_export.h"
#include "tests/hdf5_test_util.h"

#include <gtest/gtest.h>
#include <hdf5.h>

#include <fcntl.h>
#include <unistd.h>

#include <filesystem>
#include <fstream>
#include <random>
#include <sstream>
#include <string>
#include <vector>

namespace fs = std::filesystem;
using namespace fc;
using fc::test::readFile;
using fc::test::TempDir;

namespace {

template <int D>
ExportHeader makeHeader(const std::string& scene = "unit") {
  ExportHeader h;
  h.sceneName = scene;
  h.dimension = D;
  h.particleRadius = 0.025;
  h.frameRate = 60;
  Phase water;
  Phase oil;
  oil.name = "oil";
  oil.restDensity = 900;
  h.phases = {water, oil};
  h.domainMin.assign(D, -1.0);
  h.domainMax.assign(D, 2.0);
  h.createdBy = "flowclip tests";
  return h;
}

// Deterministic, non-trivial particles: n of them, ids offset by `seed`.
template <int D>
FluidParticles<D> makeFluid(size_t n, unsigned seed) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<float> u(-1, 1);
  FluidParticles<D> f;
  for (size_t i = 0; i < n; ++i) {
    Vec<D> x, v;
    for (int d = 0; d < D; ++d) {
      x[d] = Real(u(rng));
      v[d] = Real(u(rng) * 3);
    }
    f.add(x, v, Real(0.1), uint8_t(i % 2), i % 5 == 4 ? ParticleKind::Temporary : ParticleKind::Liquid);
    f.density.back() = Real(1000 + 10 * u(rng));
    f.meanPressure.back() = Real(500 * u(rng));
    f.id.back() = uint32_t(seed * 1000 + (n - i));  // not simply the row number
  }
  return f;
}

// --- reading back with the HDF5 C API ---------------------------------------

struct H5 {
  hid_t id;
  herr_t (*close)(hid_t);
  ~H5() {
    if (id >= 0) close(id);
  }
};

std::vector<hsize_t> shapeOf(hid_t file, const char* name) {
  H5 ds{H5Dopen2(file, name, H5P_DEFAULT), H5Dclose};
  EXPECT_GE(ds.id, 0) << name;
  if (ds.id < 0) return {};
  H5 space{H5Dget_space(ds.id), H5Sclose};
  std::vector<hsize_t> dims(H5Sget_simple_extent_ndims(space.id));
  H5Sget_simple_extent_dims(space.id, dims.data(), nullptr);
  return dims;
}

// Reads a whole dataset, checking its stored type is exactly `fileType`.
template <class T>
std::vector<T> readAll(hid_t file, const char* name, hid_t fileType, hid_t memType) {
  H5 ds{H5Dopen2(file, name, H5P_DEFAULT), H5Dclose};
  EXPECT_GE(ds.id, 0) << name;
  if (ds.id < 0) return {};
  H5 type{H5Dget_type(ds.id), H5Tclose};
  EXPECT_GT(H5Tequal(type.id, fileType), 0) << name << " has the wrong stored type";
  size_t total = 1;
  for (hsize_t d : shapeOf(file, name)) total *= d;
  std::vector<T> out(total);
  if (total) {
    EXPECT_GE(H5Dread(ds.id, memType, H5S_ALL, H5S_ALL, H5P_DEFAULT, out.data()), 0) << name;
  }
  return out;
}

template <class T>
std::vector<T> readAttr(hid_t file, const char* name, hid_t fileType, hid_t memType) {
  H5 a{H5Aopen(file, name, H5P_DEFAULT), H5Aclose};
  EXPECT_GE(a.id, 0) << name;
  if (a.id < 0) return {};
  H5 type{H5Aget_type(a.id), H5Tclose};
  EXPECT_GT(H5Tequal(type.id, fileType), 0) << "attribute " << name << " has the wrong stored type";
  H5 space{H5Aget_space(a.id), H5Sclose};
  std::vector<T> out(size_t(H5Sget_simple_extent_npoints(space.id)));
  EXPECT_GE(H5Aread(a.id, memType, out.data()), 0) << name;
  return out;
}

std::vector<std::string> readStringAttr(hid_t file, const char* name) {
  H5 a{H5Aopen(file, name, H5P_DEFAULT), H5Aclose};
  EXPECT_GE(a.id, 0) << name;
  if (a.id < 0) return {};
  H5 type{H5Aget_type(a.id), H5Tclose};
  EXPECT_EQ(H5Tget_class(type.id), H5T_STRING) << name;
  EXPECT_GT(H5Tis_variable_str(type.id), 0) << name;
  EXPECT_EQ(H5Tget_cset(type.id), H5T_CSET_UTF8) << name;
  H5 space{H5Aget_space(a.id), H5Sclose};
  std::vector<char*> raw(size_t(H5Sget_simple_extent_npoints(space.id)));
  EXPECT_GE(H5Aread(a.id, type.id, raw.data()), 0) << name;
  std::vector<std::string> out(raw.begin(), raw.end());
  H5Dvlen_reclaim(type.id, space.id, H5P_DEFAULT, raw.data());
  return out;
}

template <int D>
void expectFileHolds(const std::string& path, const ExportHeader& h, const std::vector<int>& indices,
                     const std::vector<double>& times, const std::vector<FluidParticles<D>>& frames) {
  ASSERT_GT(H5Fis_hdf5(path.c_str()), 0) << path;
  H5 file{H5Fopen(path.c_str(), H5F_ACC_RDONLY, H5P_DEFAULT), H5Fclose};
  ASSERT_GE(file.id, 0);
  const hid_t f = file.id;

  EXPECT_EQ(readStringAttr(f, "format"), std::vector<std::string>{"flowclip-frames"});
  EXPECT_EQ(readAttr<int>(f, "format_version", H5T_STD_I32LE, H5T_NATIVE_INT), std::vector<int>{1});
  EXPECT_EQ(readAttr<int>(f, "dimension", H5T_STD_I32LE, H5T_NATIVE_INT), std::vector<int>{D});
  EXPECT_EQ(readStringAttr(f, "scene"), std::vector<std::string>{h.sceneName});
  EXPECT_EQ(readAttr<double>(f, "particle_radius", H5T_IEEE_F64LE, H5T_NATIVE_DOUBLE),
            std::vector<double>{h.particleRadius});
  EXPECT_EQ(readAttr<double>(f, "frame_rate", H5T_IEEE_F64LE, H5T_NATIVE_DOUBLE), std::vector<double>{h.frameRate});
  EXPECT_EQ(readAttr<double>(f, "domain_min", H5T_IEEE_F64LE, H5T_NATIVE_DOUBLE), h.domainMin);
  EXPECT_EQ(readAttr<double>(f, "domain_max", H5T_IEEE_F64LE, H5T_NATIVE_DOUBLE), h.domainMax);
  EXPECT_EQ(readStringAttr(f, "created_by"), std::vector<std::string>{h.createdBy});
  std::vector<std::string> names;
  std::vector<double> rho;
  for (auto& p : h.phases) {
    names.push_back(p.name);
    rho.push_back(double(p.restDensity));
  }
  EXPECT_EQ(readStringAttr(f, "phase_names"), names);
  EXPECT_EQ(readAttr<double>(f, "phase_rest_density", H5T_IEEE_F64LE, H5T_NATIVE_DOUBLE), rho);

  const size_t F = frames.size();
  size_t N = 0;
  for (auto& fr : frames) N += fr.size();
  EXPECT_EQ(shapeOf(f, "/frames/index"), std::vector<hsize_t>{F});
  EXPECT_EQ(shapeOf(f, "/frames/time"), std::vector<hsize_t>{F});
  EXPECT_EQ(shapeOf(f, "/frames/offset"), std::vector<hsize_t>{F + 1});
  EXPECT_EQ(shapeOf(f, "/frames/count"), std::vector<hsize_t>{F});
  EXPECT_EQ(shapeOf(f, "/particles/position"), (std::vector<hsize_t>{N, hsize_t(D)}));
  EXPECT_EQ(shapeOf(f, "/particles/velocity"), (std::vector<hsize_t>{N, hsize_t(D)}));
  for (const char* name : {"/particles/density", "/particles/pressure", "/particles/phase", "/particles/kind",
                           "/particles/id"})
    EXPECT_EQ(shapeOf(f, name), std::vector<hsize_t>{N}) << name;

  const auto index = readAll<uint32_t>(f, "/frames/index", H5T_STD_U32LE, H5T_NATIVE_UINT32);
  const auto time = readAll<double>(f, "/frames/time", H5T_IEEE_F64LE, H5T_NATIVE_DOUBLE);
  const auto offset = readAll<uint64_t>(f, "/frames/offset", H5T_STD_U64LE, H5T_NATIVE_UINT64);
  const auto count = readAll<uint32_t>(f, "/frames/count", H5T_STD_U32LE, H5T_NATIVE_UINT32);
  const auto pos = readAll<float>(f, "/particles/position", H5T_IEEE_F32LE, H5T_NATIVE_FLOAT);
  const auto vel = readAll<float>(f, "/particles/velocity", H5T_IEEE_F32LE, H5T_NATIVE_FLOAT);
  const auto dens = readAll<float>(f, "/particles/density", H5T_IEEE_F32LE, H5T_NATIVE_FLOAT);
  const auto pres = readAll<float>(f, "/particles/pressure", H5T_IEEE_F32LE, H5T_NATIVE_FLOAT);
  const auto phase = readAll<uint8_t>(f, "/particles/phase", H5T_STD_U8LE, H5T_NATIVE_UINT8);
  const auto kind = readAll<uint8_t>(f, "/particles/kind", H5T_STD_U8LE, H5T_NATIVE_UINT8);
  const auto id = readAll<uint32_t>(f, "/particles/id", H5T_STD_U32LE, H5T_NATIVE_UINT32);
  ASSERT_EQ(offset.size(), F + 1);
  ASSERT_EQ(id.size(), N);
  EXPECT_EQ(offset[0], 0u);
  for (size_t k = 0; k < F; ++k) {
    const auto& fr = frames[k];
    EXPECT_EQ(index[k], uint32_t(indices[k]));
    EXPECT_EQ(time[k], times[k]);
    EXPECT_EQ(count[k], fr.size());
    ASSERT_EQ(offset[k + 1] - offset[k], fr.size()) << "frame " << k;
    for (size_t i = 0; i < fr.size(); ++i) {
      const size_t r = offset[k] + i;
      for (int d = 0; d < D; ++d) {
        ASSERT_EQ(pos[r * D + d], float(fr.x[i][d])) << "frame " << k << " particle " << i;
        ASSERT_EQ(vel[r * D + d], float(fr.v[i][d])) << "frame " << k << " particle " << i;
      }
      ASSERT_EQ(dens[r], float(fr.density[i]));
      ASSERT_EQ(pres[r], float(fr.meanPressure[i]));
      ASSERT_EQ(phase[r], fr.phase[i]);
      ASSERT_EQ(kind[r], fr.kind[i]);
      ASSERT_EQ(id[r], fr.id[i]);
    }
  }
}

template <int D>
void roundTrip() {
  TempDir dir;
  const std::string path = dir.file("frames.h5");
  const ExportHeader h = makeHeader<D>("round trip " + std::to_string(D) + "d");
  // Ragged: the count changes every frame, and one frame is empty.
  std::vector<FluidParticles<D>> frames = {makeFluid<D>(37, 1), makeFluid<D>(0, 2), makeFluid<D>(101, 3),
                                           makeFluid<D>(64, 4)};
  const std::vector<int> indices = {0, 1, 2, 7};
  const std::vector<double> times = {0.0, 1.0 / 60, 2.0 / 60, 7.0 / 60};
  {
    FrameExporter<D> ex(path, h);
    // Hidden, beside the final name, named for recoverPublishing().
    EXPECT_EQ(fs::path(ex.tempPath()).parent_path(), fs::path(path).parent_path());
    EXPECT_EQ(fs::path(ex.tempPath()).filename().string().rfind(".frames.h5.stage-" + std::to_string(::getpid()) + "-", 0), 0u);
    for (size_t k = 0; k < frames.size(); ++k) {
      ex.writeFrame(indices[k], times[k], frames[k]);
      EXPECT_FALSE(fs::exists(path)) << "published before close";
      EXPECT_TRUE(fs::exists(ex.tempPath()));
    }
    EXPECT_EQ(ex.frameCount(), 4);
    EXPECT_EQ(ex.particleRowCount(), 202u);
    ex.close();
    EXPECT_FALSE(ex.isOpen());
    ex.close();  // idempotent
  }
  EXPECT_EQ(dir.entries(), std::vector<std::string>{"frames.h5"}) << "temporary file left behind";
  expectFileHolds<D>(path, h, indices, times, frames);
}

void writeText(const std::string& path, const std::string& text) {
  std::ofstream out(path, std::ios::binary);
  out << text;
}

}  // namespace

TEST(FrameExport, RoundTrip2D) { roundTrip<2>(); }
TEST(FrameExport, RoundTrip3D) { roundTrip<3>(); }

TEST(FrameExport, LargeFramesSpanSeveralChunks) {
  // More rows than one 64k chunk, split across frames at non-chunk borders.
  TempDir dir;
  const std::string path = dir.file("big.h5");
  const ExportHeader h = makeHeader<3>();
  std::vector<FluidParticles<3>> frames = {makeFluid<3>(70000, 5), makeFluid<3>(90001, 6)};
  {
    FrameExporter<3> ex(path, h);
    ex.writeFrame(3, 0.5, frames[0]);
    ex.writeFrame(4, 0.5 + 1.0 / 60, frames[1]);
  }  // the destructor publishes
  expectFileHolds<3>(path, h, {3, 4}, {0.5, 0.5 + 1.0 / 60}, frames);
}

TEST(FrameExport, ExistingFileUntouchedUntilClose) {
  TempDir dir;
  const std::string path = dir.file("out.h5");
  writeText(path, "previous export");
  const ExportHeader h = makeHeader<2>();
  const auto fluid = makeFluid<2>(10, 7);
  FrameExporter<2> ex(path, h);
  for (int k = 0; k < 3; ++k) {
    ex.writeFrame(k, k / 60.0, fluid);
    EXPECT_EQ(readFile(path), "previous export");
  }
  ex.close();
  expectFileHolds<2>(path, h, {0, 1, 2}, {0, 1 / 60.0, 2 / 60.0}, {fluid, fluid, fluid});
  EXPECT_EQ(dir.entries(), std::vector<std::string>{"out.h5"});
}

TEST(FrameExport, NonExistentDirectoryThrowsNamingThePath) {
  TempDir dir;
  const std::string path = dir.file("no/such/dir/out.h5");
  try {
    FrameExporter<3> ex(path, makeHeader<3>());
    FAIL() << "expected an exception";
  } catch (const std::runtime_error& e) {
    EXPECT_NE(std::string(e.what()).find(path), std::string::npos) << e.what();
  }
  EXPECT_TRUE(dir.entries().empty());
}

TEST(FrameExport, AbortAndFailedRunNeverPublish) {
  TempDir dir;
  const std::string path = dir.file("out.h5");
  writeText(path, "previous export");
  const auto fluid = makeFluid<2>(10, 8);
  {
    FrameExporter<2> ex(path, makeHeader<2>());
    ex.writeFrame(0, 0, fluid);
    ex.abort();
    EXPECT_FALSE(ex.isOpen());
    EXPECT_THROW(ex.writeFrame(1, 0.1, fluid), std::runtime_error);
  }
  EXPECT_EQ(readFile(path), "previous export");
  EXPECT_EQ(dir.entries(), std::vector<std::string>{"out.h5"});

  // An exception unwinding through the exporter's scope: the run failed, its
  // partial output is discarded and the previous file stays.
  try {
    FrameExporter<2> ex(path, makeHeader<2>());
    ex.writeFrame(0, 0, fluid);
    throw std::logic_error("simulation blew up");
  } catch (const std::logic_error&) {
  }
  EXPECT_EQ(readFile(path), "previous export");
  EXPECT_EQ(dir.entries(), std::vector<std::string>{"out.h5"});
}

TEST(FrameExport, RejectsInconsistentInput) {
  TempDir dir;
  const std::string path = dir.file("out.h5");
  ExportHeader wrongDim = makeHeader<2>();
  EXPECT_THROW(FrameExporter<3>(path, wrongDim), std::runtime_error);
  ExportHeader wrongDomain = makeHeader<3>();
  wrongDomain.domainMax.pop_back();
  EXPECT_THROW(FrameExporter<3>(path, wrongDomain), std::runtime_error);
  EXPECT_TRUE(dir.entries().empty());

  FrameExporter<3> ex(path, makeHeader<3>());
  auto fluid = makeFluid<3>(5, 9);
  fluid.id.pop_back();
  EXPECT_THROW(ex.writeFrame(0, 0, fluid), std::runtime_error);
  EXPECT_THROW(ex.writeFrame(-1, 0, makeFluid<3>(5, 9)), std::runtime_error);
  // Rejected frames leave nothing behind; the exporter stays usable.
  ex.writeFrame(0, 0, makeFluid<3>(5, 9));
  ex.close();
  expectFileHolds<3>(path, makeHeader<3>(), {0}, {0.0}, {makeFluid<3>(5, 9)});
}

// The file descriptor through which HDF5 writes `path`, found in /proc.
int descriptorOf(const std::string& path) {
  const fs::path target = fs::weakly_canonical(path);
  for (const auto& e : fs::directory_iterator("/proc/self/fd")) {
    std::error_code ec;
    if (fs::read_symlink(e.path(), ec) == target && !ec) return std::stoi(e.path().filename().string());
  }
  return -1;
}

TEST(FrameExport, WriteErrorRemovesTemporaryFile) {
  // An I/O error (full disk, failing device) while frames are written: the
  // descriptor HDF5 writes through is swapped for a read-only one, so every
  // later write fails. With 70,000 particles the error hits writeFrame (a
  // whole chunk is written); with 10 it hits close (the last partial chunk).
  for (size_t n : {70000, 10}) {
    SCOPED_TRACE("particles per frame: " + std::to_string(n));
    TempDir dir;
    const std::string path = dir.file("out.h5");
    writeText(path, "previous export");
    std::string message;
    try {
      FrameExporter<3> ex(path, makeHeader<3>());
      const int fd = descriptorOf(ex.tempPath());
      ASSERT_GE(fd, 0) << "no open descriptor for " << ex.tempPath();
      const int readOnly = ::open(ex.tempPath().c_str(), O_RDONLY | O_CLOEXEC);
      ASSERT_GE(readOnly, 0);
      ASSERT_GE(::dup2(readOnly, fd), 0);
      ::close(readOnly);
      const auto fluid = makeFluid<3>(n, 10);
      ex.writeFrame(0, 0, fluid);
      ex.writeFrame(1, 1 / 60.0, fluid);
      ex.close();
    } catch (const std::runtime_error& e) {
      message = e.what();
    }
    EXPECT_NE(message.find(path), std::string::npos) << "no error naming the path: '" << message << "'";
    EXPECT_EQ(readFile(path), "previous export");
    EXPECT_EQ(dir.entries(), std::vector<std::string>{"out.h5"}) << "temporary file left behind";
  }
  // The process must also exit cleanly afterwards (ctest runs each test in
  // its own process): HDF5 must hold no half-closed file.
}

TEST(FrameExport, EmptyExportIsValid) {
  TempDir dir;
  const std::string path = dir.file("empty.h5");
  ExportHeader h = makeHeader<2>();
  { FrameExporter<2> ex(path, h); }
  expectFileHolds<2>(path, h, {}, {}, std::vector<FluidParticles<2>>{});
}
