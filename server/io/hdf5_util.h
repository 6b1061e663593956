// Small HDF5 helpers shared by the io/ readers and writers (frame_export.cpp,
// template_file.cpp). Everything lives in namespace fc::hdf5.
//
// Error reporting: inside a Quiet guard HDF5 prints nothing. Wrap every call
// whose failure is reported in checked(): the error stack of the first failed
// call is kept (later calls, such as the closes on the way out, clear HDF5's
// stack), and takeError() gives it for the exception message.
#pragma once

#include <hdf5.h>

#include <string>
#include <vector>

namespace fc::hdf5 {

// Closes an HDF5 identifier at scope exit.
class Handle {
 public:
  Handle(hid_t id, herr_t (*closer)(hid_t)) : id_(id), closer_(closer) {}
  ~Handle() {
    if (id_ >= 0) closer_(id_);
  }
  Handle(Handle&& o) noexcept : id_(o.id_), closer_(o.closer_) { o.id_ = -1; }
  Handle(const Handle&) = delete;
  Handle& operator=(const Handle&) = delete;
  Handle& operator=(Handle&&) = delete;
  hid_t get() const { return id_; }
  // Gives up ownership (to close it explicitly and check the result).
  hid_t release() {
    const hid_t id = id_;
    id_ = -1;
    return id;
  }
  bool ok() const { return id_ >= 0; }

 private:
  hid_t id_;
  herr_t (*closer_)(hid_t);
};

// Silences HDF5's automatic error printing while we call it: failures are
// reported once, through the exception, with the library's own messages.
// Also forgets the error kept by checked() (this thread's).
class Quiet {
 public:
  Quiet();
  ~Quiet();
  Quiet(const Quiet&) = delete;
  Quiet& operator=(const Quiet&) = delete;

 private:
  H5E_auto2_t func_ = nullptr;
  void* data_ = nullptr;
};

// The descriptions on HDF5's current error stack: the API-level line and the
// innermost two (the innermost has errno and its message for I/O failures),
// joined with "; ", newlines replaced by spaces. Empty if the stack is empty.
std::string errorText();

// Keeps errorText() if no failure has been kept since the last Quiet guard
// (or takeError()). Called by checked().
void noteFailure();

// The text kept by checked() if any, else errorText(); forgets the kept text.
std::string takeError();

// Passes an HDF5 result through, keeping the error stack of the first failure.
template <class R>
R checked(R result) {
  if (result < 0) noteFailure();
  return result;
}

// A variable-length UTF-8 string type (close with H5Tclose), or -1.
hid_t utf8StringType();

// Attribute writers: true on success. Failures go through checked().
bool writeAttribute(hid_t loc, const char* name, hid_t fileType, hid_t memType, hid_t space, const void* data);
bool writeScalar(hid_t loc, const char* name, hid_t fileType, hid_t memType, const void* data);
// A one-dimensional attribute of n elements.
bool writeArray(hid_t loc, const char* name, hid_t fileType, hid_t memType, hsize_t n, const void* data);
// An attribute with a null dataspace (no elements).
bool writeEmpty(hid_t loc, const char* name, hid_t fileType);
bool writeString(hid_t loc, const char* name, const std::string& value);
bool writeStrings(hid_t loc, const char* name, const std::vector<std::string>& values);

// An extendible dataset of `rows` rows and `cols` columns (cols == 0:
// one-dimensional), unlimited along rows, in chunks of `chunkRows` rows,
// filtered by shuffle (multi-byte file types only) then deflate at
// `deflateLevel`. Returns the dataset (close with H5Dclose) or -1.
hid_t createDataset(hid_t loc, const char* name, hid_t fileType, hsize_t rows, int cols, hsize_t chunkRows,
                    unsigned deflateLevel);

// Opens the HDF5 file whose bytes are `bytes`, read-only, with the core
// driver and without copying them: HDF5 reads exactly these bytes (checked
// beforehand by the caller) and never the disk. `bytes` must stay alive and
// unchanged until the file and every object opened in it are closed. Returns
// the file (close with H5Fclose) or -1 (failure through checked()).
hid_t openImage(const std::vector<unsigned char>& bytes);

// fsync()s a file (or, with `directory`, a directory, to make a rename in it
// durable). Throws std::system_error with errno on failure. Not HDF5-specific;
// here because both writers publish their files with it.
void syncPath(const std::string& path, bool directory);

}  // namespace fc::hdf5
