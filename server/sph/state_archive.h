#pragma once
// A simulation's state between two frames as bytes (checkpoints): what the
// next frame reads and no step recomputes first. One function per class
// serves both directions, `archiveState(StateArchive&)`, so that what is
// saved and what is restored cannot drift apart; per-step scratch is not
// state and stays out.
#include <cstdint>
#include <cstring>
#include <stdexcept>
#include <string>
#include <type_traits>
#include <vector>

namespace fc {

namespace detail {
// Plain bytes: trivially copyable types, and fixed-size Eigen matrices (an
// array of scalars, which Eigen does not declare trivially copyable).
template <class T, class = void>
struct IsFixedEigen : std::false_type {};
template <class T>
struct IsFixedEigen<T, std::void_t<typename T::Scalar, decltype(T::SizeAtCompileTime)>>
    : std::bool_constant<(T::SizeAtCompileTime > 0) && sizeof(T) == sizeof(typename T::Scalar) * size_t(T::SizeAtCompileTime)> {};
template <class T>
inline constexpr bool kPlainBytes = std::is_trivially_copyable_v<T> || IsFixedEigen<T>::value;
}  // namespace detail

// A restore that does not match what was saved (another scene, a damaged
// checkpoint): the simulation must then be rebuilt, never stepped.
struct StateArchiveError : std::runtime_error {
  using std::runtime_error::runtime_error;
};

class StateArchive {
 public:
  enum class Mode { Save, Load };

  // Save: appends to an empty buffer.
  StateArchive() : mode_(Mode::Save) {}
  // Load: reads `bytes` (which must outlive the archive).
  explicit StateArchive(const std::vector<uint8_t>& bytes) : mode_(Mode::Load), in_(&bytes) {}

  bool saving() const { return mode_ == Mode::Save; }
  bool loading() const { return mode_ == Mode::Load; }

  // A trivially copyable value.
  template <class T>
  void io(T& value) {
    static_assert(detail::kPlainBytes<T>);
    raw(&value, sizeof(T));
  }
  // A vector of trivially copyable values (its size included).
  template <class T>
  void io(std::vector<T>& v) {
    static_assert(detail::kPlainBytes<T>);
    uint64_t n = v.size();
    io(n);
    if (loading()) {
      if (n > remaining() / (sizeof(T) ? sizeof(T) : 1)) throw StateArchiveError("checkpoint truncated");
      v.resize(size_t(n));
    }
    raw(v.data(), size_t(n) * sizeof(T));
  }
  void io(std::string& s) {
    uint64_t n = s.size();
    io(n);
    if (loading()) {
      if (n > remaining()) throw StateArchiveError("checkpoint truncated");
      s.resize(size_t(n));
    }
    raw(s.data(), size_t(n));
  }
  // A marker checked on load: a mismatch names the section, so that an
  // archive read by the wrong code fails at once instead of misreading.
  void section(const char* name) {
    std::string s = saving() ? std::string(name) : std::string();
    uint32_t n = uint32_t(std::strlen(name));
    io(n);
    if (loading()) {
      if (n > remaining()) throw StateArchiveError(std::string("checkpoint truncated before '") + name + "'");
      s.resize(n);
    }
    raw(s.data(), n);
    if (loading() && s != name)
      throw StateArchiveError("checkpoint section '" + s + "' where '" + name + "' was expected");
  }

  // A nested archive's bytes (a stage's state, found again by name on load).
  void blob(std::vector<uint8_t>& bytes) { io(bytes); }

  std::vector<uint8_t>& bytes() { return out_; }
  size_t size() const { return saving() ? out_.size() : in_->size(); }
  bool atEnd() const { return loading() && pos_ == in_->size(); }

 private:
  size_t remaining() const { return in_->size() - pos_; }
  void raw(void* p, size_t n) {
    if (saving()) {
      const auto* b = static_cast<const uint8_t*>(p);
      out_.insert(out_.end(), b, b + n);
    } else {
      if (n > remaining()) throw StateArchiveError("checkpoint truncated");
      if (n) std::memcpy(p, in_->data() + pos_, n);
      pos_ += n;
    }
  }

  Mode mode_;
  std::vector<uint8_t> out_;
  const std::vector<uint8_t>* in_ = nullptr;
  size_t pos_ = 0;
};

}  // namespace fc
