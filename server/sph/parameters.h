#pragma once
// Parameters are declared once (name, unit, range, default, help) and that
// declaration drives scene-file parsing, validation, REST and the editor's
// inspector. Values are stored as doubles; integer and boolean parameters are
// flagged so that parsers can check the JSON type.
#include <map>
#include <stdexcept>
#include <string>
#include <vector>

namespace fc {

enum class ParamType { Number, Integer, Boolean };

struct ParamSpec {
  std::string name;
  std::string unit;
  double min;
  double max;
  double def;
  std::string help;
  ParamType type = ParamType::Number;
};

using ParamSpecs = std::vector<ParamSpec>;

// Values for one set of specs; every spec has a value (its default unless set).
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

inline const ParamSpec* findSpec(const ParamSpecs& specs, const std::string& name) {
  for (const auto& s : specs)
    if (s.name == name) return &s;
  return nullptr;
}

}  // namespace fc
