#include "io/json_access.h"

#include <algorithm>
#include <cmath>
#include <sstream>

namespace fc {

using nlohmann::json;

JsonValueError::JsonValueError(std::string p, const std::string& msg)
    : std::runtime_error(p.empty() ? msg : p + ": " + msg), path(std::move(p)), message(msg) {}

namespace json_access {

std::string keyPath(const std::string& path, const std::string& key) { return path.empty() ? key : path + "." + key; }

std::string indexPath(const std::string& path, size_t index) { return path + "[" + std::to_string(index) + "]"; }

void fail(const std::string& path, const std::string& message) { throw JsonValueError(path, message); }

std::string formatNumber(double v) {
  std::ostringstream s;
  s.precision(12);
  s << v;
  return s.str();
}

std::string brief(const json& j) {
  std::string s = j.dump(-1, ' ', false, json::error_handler_t::replace);
  return s.size() <= 60 ? s : s.substr(0, 57) + "...";
}

std::string joinNames(const std::vector<std::string>& names, const std::string& none) {
  if (names.empty()) return none;
  std::string out;
  for (size_t i = 0; i < names.size(); ++i) out += (i ? ", " : "") + names[i];
  return out;
}

void expectType(bool ok, const json& j, const std::string& path, const char* expected) {
  if (!ok) fail(path, std::string("expected ") + expected + ", got " + j.type_name() + " " + brief(j));
}

const json& expectObject(const json& j, const std::string& path) {
  expectType(j.is_object(), j, path, "an object");
  return j;
}

const json& expectArray(const json& j, const std::string& path) {
  expectType(j.is_array(), j, path, "an array");
  return j;
}

void checkKeys(const json& obj, const std::string& path, const std::vector<std::string>& allowed,
               const std::string& owner) {
  for (auto it = obj.begin(); it != obj.end(); ++it)
    if (std::find(allowed.begin(), allowed.end(), it.key()) == allowed.end())
      fail(keyPath(path, it.key()), "unknown key" + (owner.empty() ? std::string() : " for " + owner) +
                                        "; expected one of: " + joinNames(allowed));
}

const json* member(const json& obj, const std::string& key) {
  auto it = obj.find(key);
  return it == obj.end() ? nullptr : &*it;
}

const json& required(const json& obj, const std::string& path, const std::string& key, const std::string& what) {
  const json* m = member(obj, key);
  if (!m) fail(keyPath(path, key), "missing required key" + (what.empty() ? std::string() : " (" + what + ")"));
  return *m;
}

double getNumber(const json& j, const std::string& path) {
  expectType(j.is_number(), j, path, "a number");
  const double v = j.get<double>();
  if (!std::isfinite(v)) fail(path, "value is not finite");
  return v;
}

double getInteger(const json& j, const std::string& path) {
  const double v = getNumber(j, path);
  if (v != std::floor(v)) fail(path, "expected an integer, got " + brief(j));
  return v;
}

std::string getString(const json& j, const std::string& path) {
  expectType(j.is_string(), j, path, "a string");
  return j.get<std::string>();
}

bool getBool(const json& j, const std::string& path) {
  expectType(j.is_boolean(), j, path, "true or false");
  return j.get<bool>();
}

std::string rangeText(const Bounds& b) {
  return "[" + formatNumber(b.min) + ", " + formatNumber(b.max) + "]" + (b.unit.empty() ? "" : " " + b.unit);
}

double checkBounds(double v, const std::string& path, const Bounds& b) {
  if (!(v >= b.min && v <= b.max))
    fail(path, formatNumber(v) + " is outside the " + b.kind + " range " + rangeText(b) +
                   (b.why.empty() ? "" : " (" + b.why + ")"));
  return v;
}

double numberField(const json& obj, const std::string& path, const std::string& key, std::optional<double> fallback,
                   const Bounds& bounds) {
  const json* m = fallback ? member(obj, key) : &required(obj, path, key);
  if (!m) return *fallback;
  const std::string p = keyPath(path, key);
  return checkBounds(getNumber(*m, p), p, bounds);
}

int64_t integerField(const json& obj, const std::string& path, const std::string& key, std::optional<int64_t> fallback,
                     const Bounds& bounds) {
  const json* m = fallback ? member(obj, key) : &required(obj, path, key);
  if (!m) return *fallback;
  const std::string p = keyPath(path, key);
  const double v = checkBounds(getInteger(*m, p), p, bounds);
  constexpr double kExact = 9007199254740992.0;  // 2^53
  if (std::abs(v) > kExact) fail(p, formatNumber(v) + " is too large for an integer (at most 2^53)");
  return int64_t(v);
}

std::string stringField(const json& obj, const std::string& path, const std::string& key,
                        std::optional<std::string> fallback) {
  const json* m = fallback ? member(obj, key) : &required(obj, path, key);
  if (!m) return *fallback;
  return getString(*m, keyPath(path, key));
}

bool boolField(const json& obj, const std::string& path, const std::string& key, std::optional<bool> fallback) {
  const json* m = fallback ? member(obj, key) : &required(obj, path, key);
  if (!m) return *fallback;
  return getBool(*m, keyPath(path, key));
}

}  // namespace json_access
}  // namespace fc
