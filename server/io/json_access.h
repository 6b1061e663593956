#pragma once
// Typed access to JSON that users write: scene files, recipes, REST bodies,
// edits. Every error is a JsonValueError that names the key path of the
// value, what was expected instead, and for a number out of bounds the range,
// its unit and why it is bounded. Scene parsing reports it as it is
// (SceneError is this type); the REST handlers answer it as 400 with the path.
#include <nlohmann/json.hpp>

#include <cstdint>
#include <limits>
#include <optional>
#include <stdexcept>
#include <string>
#include <vector>

namespace fc {

// A JSON value that is not what it must be. `path` locates it the way a user
// types it (`fluid_blocks[1].min[0]`, `first_frame`); it is empty for the
// document as a whole. what() is "<path>: <message>", or the message alone
// when the path is empty.
struct JsonValueError : std::runtime_error {
  JsonValueError(std::string path, const std::string& message);
  std::string path;
  std::string message;  // what() without the path
};

namespace json_access {

// ---- key paths and messages ----------------------------------------------------------

// "a.b" ("b" at the root, path "").
std::string keyPath(const std::string& path, const std::string& key);
// "a[2]".
std::string indexPath(const std::string& path, size_t index);

[[noreturn]] void fail(const std::string& path, const std::string& message);

// A number as messages print it: up to 12 significant digits, no trailing zeros.
std::string formatNumber(double v);
// The value as written, cut to 60 characters (a misplaced object can be large).
std::string brief(const nlohmann::json& j);
// "a, b, c"; `none` when the list is empty.
std::string joinNames(const std::vector<std::string>& names, const std::string& none = "(none)");

// ---- types -----------------------------------------------------------------------------

// Fails at `path` with "expected <expected>, got <type> <value>" unless `ok`.
void expectType(bool ok, const nlohmann::json& j, const std::string& path, const char* expected);
const nlohmann::json& expectObject(const nlohmann::json& j, const std::string& path);
const nlohmann::json& expectArray(const nlohmann::json& j, const std::string& path);

// Unknown keys are errors, so that a typo never falls back to a default: the
// first key of `obj` not in `allowed` fails at its path, listing the
// accepted ones. `owner` ("a settings edit") is named in the message if given.
void checkKeys(const nlohmann::json& obj, const std::string& path, const std::vector<std::string>& allowed,
               const std::string& owner = {});

// obj[key], or nullptr when absent.
const nlohmann::json* member(const nlohmann::json& obj, const std::string& key);
// obj[key]; absent, fails at path.key: "missing required key (<what>)".
const nlohmann::json& required(const nlohmann::json& obj, const std::string& path, const std::string& key,
                               const std::string& what = {});

// The value at `path` as a finite number.
double getNumber(const nlohmann::json& j, const std::string& path);
// A finite number without a fraction: JSON has one number type, so 3.0 is
// the integer 3.
double getInteger(const nlohmann::json& j, const std::string& path);
std::string getString(const nlohmann::json& j, const std::string& path);
bool getBool(const nlohmann::json& j, const std::string& path);

// ---- bounds ----------------------------------------------------------------------------

// A closed interval and what the message says of it.
struct Bounds {
  double min = -std::numeric_limits<double>::infinity();
  double max = std::numeric_limits<double>::infinity();
  std::string unit;              // after the interval: "[0, 1] m"
  std::string why;               // in parentheses after it: what the bound is for
  std::string kind = "allowed";  // "the allowed range", "the physical range"

  Bounds() = default;  // any finite value
  Bounds(double min, double max, std::string unit = {}, std::string why = {}, std::string kind = "allowed")
      : min(min), max(max), unit(std::move(unit)), why(std::move(why)), kind(std::move(kind)) {}
};

// Bounds of a declaration with min, max, unit and help (PhysicalRange in
// sph/limits.h, ParamSpec in sph/parameters.h).
template <class Declared>
Bounds boundsOf(const Declared& d, const std::string& kind = "allowed") {
  return Bounds{double(d.min), double(d.max), std::string(d.unit), std::string(d.help), kind};
}

// "[min, max] unit".
std::string rangeText(const Bounds& b);
// v, or a failure at `path`: "<v> is outside the <kind> range [min, max] <unit> (<why>)".
double checkBounds(double v, const std::string& path, const Bounds& b);

// ---- fields of an object ---------------------------------------------------------------
// obj[key] at path.key, checked; when absent, `fallback`, or without one
// (kRequired) "missing required key".

inline constexpr std::nullopt_t kRequired = std::nullopt;

double numberField(const nlohmann::json& obj, const std::string& path, const std::string& key,
                   std::optional<double> fallback, const Bounds& bounds = {});
// Also refused: integers beyond 2^53, which a double cannot hold exactly.
int64_t integerField(const nlohmann::json& obj, const std::string& path, const std::string& key,
                     std::optional<int64_t> fallback, const Bounds& bounds = {});
std::string stringField(const nlohmann::json& obj, const std::string& path, const std::string& key,
                        std::optional<std::string> fallback);
bool boolField(const nlohmann::json& obj, const std::string& path, const std::string& key,
               std::optional<bool> fallback);

}  // namespace json_access
}  // namespace fc
