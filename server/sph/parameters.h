#pragma once
// Parameters are declared once, as rows of a ParamTable: name, unit, range,
// default, help and the typed member the value lands in. That table drives
// scene-file parsing, validation, REST, the editor's inspector and the
// generated parameter reference (`flowclip params`); the code that runs
// reads the typed members, never a name. ParamValues carries the values by
// name between the scene file and a table's bind().
#include <cmath>
#include <initializer_list>
#include <map>
#include <stdexcept>
#include <string>
#include <string_view>
#include <type_traits>
#include <utility>
#include <variant>
#include <vector>

namespace fc {

enum class ParamType { Number, Integer, Boolean };

// Members left out of a designated initializer take these defaults.
struct ParamSpec {
  std::string name{};
  std::string unit{};
  double min = 0;
  double max = 0;
  double def = 0;
  std::string help{};
  ParamType type = ParamType::Number;
};

using ParamSpecs = std::vector<ParamSpec>;

inline const ParamSpec* findSpec(const ParamSpecs& specs, const std::string& name) {
  for (const auto& s : specs)
    if (s.name == name) return &s;
  return nullptr;
}

// Values by name for one set of specs; every spec has a value (its default
// unless set).
class ParamValues {
 public:
  ParamValues() = default;
  explicit ParamValues(const ParamSpecs& specs) {
    for (const auto& s : specs) values_[s.name] = s.def;
  }
  double get(const std::string& name) const {
    auto it = values_.find(name);
    if (it == values_.end()) throw std::logic_error("undeclared parameter '" + name + "'");
    return it->second;
  }
  void set(const std::string& name, double v) { values_[name] = v; }
  bool has(const std::string& name) const { return values_.count(name) != 0; }
  const std::map<std::string, double>& all() const { return values_; }

 private:
  std::map<std::string, double> values_;
};

// The member of T a parameter is bound to; its type gives the parameter's.
template <class T>
using ParamMember = std::variant<double T::*, float T::*, int T::*, bool T::*>;

// One row of a ParamTable, written with designated initializers:
//   {.name = "coefficient", .min = 0, .max = 1, .def = 0.05,
//    .help = "XSPH smoothing factor c", .member = &XsphParams::coefficient}
template <class T>
struct Param {
  std::string name{};
  std::string unit{};
  double min = 0;
  double max = 0;
  double def = 0;
  std::string help{};
  ParamMember<T> member{};
};

// The declaration of a parameter struct T: its specs (for parsing, REST and
// the docs) and the binding of each to its member.
template <class T>
class ParamTable {
 public:
  ParamTable(std::initializer_list<Param<T>> rows) {
    for (const Param<T>& r : rows) {
      specs_.push_back(
          {.name = r.name, .unit = r.unit, .min = r.min, .max = r.max, .def = r.def, .help = r.help, .type = typeOf(r.member)});
      members_.push_back(r.member);
    }
  }

  const ParamSpecs& specs() const { return specs_; }

  // Typed values from named ones; a name missing from v takes its default.
  T bind(const ParamValues& v) const {
    T t{};
    for (size_t i = 0; i < specs_.size(); ++i) store(t, i, v.has(specs_[i].name) ? v.get(specs_[i].name) : specs_[i].def);
    return t;
  }
  T defaults() const { return bind(ParamValues()); }

  // Named values (booleans 0/1) of t, every declared parameter present.
  ParamValues values(const T& t) const {
    ParamValues v;
    for (size_t i = 0; i < specs_.size(); ++i) v.set(specs_[i].name, load(t, i));
    return v;
  }

  // Sets one parameter by name; false when T has no such parameter.
  bool assign(T& t, std::string_view name, double value) const {
    for (size_t i = 0; i < specs_.size(); ++i)
      if (specs_[i].name == name) {
        store(t, i, value);
        return true;
      }
    return false;
  }

  // The same table with some defaults changed (e.g. the 3D weights).
  ParamTable withDefaults(std::initializer_list<std::pair<std::string_view, double>> defaults) const {
    ParamTable copy = *this;
    for (const auto& [name, def] : defaults) {
      bool found = false;
      for (ParamSpec& s : copy.specs_)
        if (s.name == name) s.def = def, found = true;
      if (!found) throw std::logic_error("undeclared parameter '" + std::string(name) + "'");
    }
    return copy;
  }

 private:
  static ParamType typeOf(const ParamMember<T>& m) {
    if (std::holds_alternative<int T::*>(m)) return ParamType::Integer;
    if (std::holds_alternative<bool T::*>(m)) return ParamType::Boolean;
    return ParamType::Number;
  }
  // GCC 12 warns (-Warray-bounds) for the alternatives a small T cannot hold, which are never the active one.
#if defined(__GNUC__) && !defined(__clang__)
#pragma GCC diagnostic push
#pragma GCC diagnostic ignored "-Warray-bounds"
#endif
  void store(T& t, size_t i, double v) const {
    std::visit(
        [&](auto member) {
          using V = std::remove_reference_t<decltype(t.*member)>;
          if constexpr (std::is_same_v<V, bool>) t.*member = v != 0;
          else if constexpr (std::is_same_v<V, int>) t.*member = int(std::llround(v));
          else t.*member = V(v);
        },
        members_[i]);
  }
#if defined(__GNUC__) && !defined(__clang__)
#pragma GCC diagnostic pop
#endif
  double load(const T& t, size_t i) const {
    return std::visit([&](auto member) { return double(t.*member); }, members_[i]);
  }

  ParamSpecs specs_;
  std::vector<ParamMember<T>> members_;
};

}  // namespace fc
