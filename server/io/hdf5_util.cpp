#include "io/hdf5_util.h"

#include <fcntl.h>
#include <unistd.h>

#include <atomic>
#include <cerrno>
#include <string>
#include <system_error>

namespace fc::hdf5 {

namespace {

// The error stack of the first failed checked() call since the last Quiet
// guard was set up (or takeError()).
thread_local std::string tFirstError;

}  // namespace

Quiet::Quiet() {
  H5Eget_auto2(H5E_DEFAULT, &func_, &data_);
  H5Eset_auto2(H5E_DEFAULT, nullptr, nullptr);
  tFirstError.clear();
}

Quiet::~Quiet() { H5Eset_auto2(H5E_DEFAULT, func_, data_); }

std::string errorText() {
  std::vector<std::string> lines;
  H5Ewalk2(
      H5E_DEFAULT, H5E_WALK_DOWNWARD,
      [](unsigned, const H5E_error2_t* e, void* out) -> herr_t {
        if (e && e->desc && *e->desc) static_cast<std::vector<std::string>*>(out)->push_back(e->desc);
        return 0;
      },
      &lines);
  // The API-level line and the innermost two carry the useful information
  // (the innermost one has errno and its message for I/O failures).
  std::string s;
  const size_t n = lines.size();
  for (size_t i = 0; i < n; ++i) {
    if (i != 0 && i + 2 < n) continue;
    if (!s.empty()) s += "; ";
    s += lines[i];
  }
  for (char& c : s)
    if (c == '\n' || c == '\r') c = ' ';
  return s;
}

void noteFailure() {
  if (tFirstError.empty()) tFirstError = errorText();
}

std::string takeError() {
  std::string detail = tFirstError.empty() ? errorText() : tFirstError;
  tFirstError.clear();
  return detail;
}

hid_t utf8StringType() {
  hid_t t = checked(H5Tcopy(H5T_C_S1));
  if (t < 0) return t;
  if (checked(H5Tset_size(t, H5T_VARIABLE)) < 0 || checked(H5Tset_cset(t, H5T_CSET_UTF8)) < 0) {
    H5Tclose(t);
    return -1;
  }
  return t;
}

bool writeAttribute(hid_t loc, const char* name, hid_t fileType, hid_t memType, hid_t space, const void* data) {
  Handle attr(checked(H5Acreate2(loc, name, fileType, space, H5P_DEFAULT, H5P_DEFAULT)), H5Aclose);
  return attr.ok() && checked(H5Awrite(attr.get(), memType, data)) >= 0;
}

bool writeScalar(hid_t loc, const char* name, hid_t fileType, hid_t memType, const void* data) {
  Handle space(checked(H5Screate(H5S_SCALAR)), H5Sclose);
  return space.ok() && writeAttribute(loc, name, fileType, memType, space.get(), data);
}

bool writeArray(hid_t loc, const char* name, hid_t fileType, hid_t memType, hsize_t n, const void* data) {
  Handle space(checked(H5Screate_simple(1, &n, nullptr)), H5Sclose);
  return space.ok() && writeAttribute(loc, name, fileType, memType, space.get(), data);
}

bool writeEmpty(hid_t loc, const char* name, hid_t fileType) {
  Handle space(checked(H5Screate(H5S_NULL)), H5Sclose);
  if (!space.ok()) return false;
  Handle attr(checked(H5Acreate2(loc, name, fileType, space.get(), H5P_DEFAULT, H5P_DEFAULT)), H5Aclose);
  return attr.ok();
}

bool writeString(hid_t loc, const char* name, const std::string& value) {
  Handle type(utf8StringType(), H5Tclose);
  const char* p = value.c_str();
  return type.ok() && writeScalar(loc, name, type.get(), type.get(), &p);
}

bool writeStrings(hid_t loc, const char* name, const std::vector<std::string>& values) {
  Handle type(utf8StringType(), H5Tclose);
  std::vector<const char*> p;
  for (auto& v : values) p.push_back(v.c_str());
  return type.ok() && writeArray(loc, name, type.get(), type.get(), p.size(), p.data());
}

hid_t createDataset(hid_t loc, const char* name, hid_t fileType, hsize_t rows, int cols, hsize_t chunkRows,
                    unsigned deflateLevel) {
  const int rank = cols > 0 ? 2 : 1;
  const hsize_t dims[2] = {rows, hsize_t(cols)};
  const hsize_t maxDims[2] = {H5S_UNLIMITED, hsize_t(cols)};
  const hsize_t chunk[2] = {chunkRows, hsize_t(cols)};
  Handle space(checked(H5Screate_simple(rank, dims, maxDims)), H5Sclose);
  Handle dcpl(checked(H5Pcreate(H5P_DATASET_CREATE)), H5Pclose);
  if (!space.ok() || !dcpl.ok()) return -1;
  if (checked(H5Pset_chunk(dcpl.get(), rank, chunk)) < 0) return -1;
  if (H5Tget_size(fileType) > 1 && checked(H5Pset_shuffle(dcpl.get())) < 0) return -1;
  if (checked(H5Pset_deflate(dcpl.get(), deflateLevel)) < 0) return -1;
  return checked(H5Dcreate2(loc, name, fileType, space.get(), H5P_DEFAULT, dcpl.get(), H5P_DEFAULT));
}

namespace {

// File image callbacks that hand HDF5 the caller's bytes instead of copies
// (udata is the caller's vector). HDF5 only ever "copies" the image onto
// itself; any other copy, and any growth, is refused: the file is read-only.
void* imageMalloc(size_t size, H5FD_file_image_op_t, void* udata) {
  auto* bytes = static_cast<std::vector<unsigned char>*>(udata);
  return size == bytes->size() ? bytes->data() : nullptr;
}
void* imageMemcpy(void* dest, const void* src, size_t, H5FD_file_image_op_t, void*) {
  return dest == src ? dest : nullptr;
}
void* imageRealloc(void*, size_t, H5FD_file_image_op_t, void*) { return nullptr; }
herr_t imageFree(void*, H5FD_file_image_op_t, void*) { return 0; }
void* udataCopy(void* udata) { return udata; }
herr_t udataFree(void*) { return 0; }

}  // namespace

hid_t openImage(const std::vector<unsigned char>& bytes) {
  if (bytes.empty()) return -1;
  auto* udata = const_cast<std::vector<unsigned char>*>(&bytes);
  H5FD_file_image_callbacks_t callbacks = {imageMalloc, imageMemcpy, imageRealloc, imageFree,
                                           udataCopy,   udataFree,   udata};
  Handle fapl(checked(H5Pcreate(H5P_FILE_ACCESS)), H5Pclose);
  if (!fapl.ok() || checked(H5Pset_fapl_core(fapl.get(), 1 << 16, false)) < 0 ||
      checked(H5Pset_fclose_degree(fapl.get(), H5F_CLOSE_STRONG)) < 0 ||
      checked(H5Pset_file_image_callbacks(fapl.get(), &callbacks)) < 0 ||
      checked(H5Pset_file_image(fapl.get(), udata->data(), bytes.size())) < 0)
    return -1;
  // The core driver refuses an image whose name exists as a file, and takes
  // two open files of the same name for one: a unique name under a regular
  // file (/dev/null), which no path can reach, satisfies both.
  static std::atomic<unsigned long> counter{0};
  const std::string name = "/dev/null/flowclip-image-" + std::to_string(counter++);
  return checked(H5Fopen(name.c_str(), H5F_ACC_RDONLY, fapl.get()));
}

void syncPath(const std::string& path, bool directory) {
  const int fd = ::open(path.c_str(), (directory ? O_DIRECTORY : 0) | O_RDONLY | O_CLOEXEC);
  if (fd < 0) throw std::system_error(errno, std::generic_category());
  const int rc = ::fsync(fd);
  const int err = errno;
  ::close(fd);
  if (rc != 0) throw std::system_error(err, std::generic_category());
}

}  // namespace fc::hdf5
