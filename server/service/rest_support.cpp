#include "service/rest_support.h"

#include "io/template_database.h"

#include <cctype>
#include <cerrno>
#include <cstdlib>
#include <sstream>

namespace fc::service::rest {

HttpResponse jsonResponse(const json& j, int status) {
  HttpResponse r;
  r.status = status;
  // Replace rather than throw on invalid UTF-8 from file names or scene text.
  r.body = j.dump(-1, ' ', false, json::error_handler_t::replace);
  return r;
}

std::string percentDecode(const std::string& s) {
  std::string out;
  out.reserve(s.size());
  for (size_t i = 0; i < s.size(); ++i) {
    if (s[i] == '%' && i + 2 < s.size() && std::isxdigit(uint8_t(s[i + 1])) && std::isxdigit(uint8_t(s[i + 2]))) {
      out.push_back(char(std::stoi(s.substr(i + 1, 2), nullptr, 16)));
      i += 2;
    } else {
      out.push_back(s[i]);
    }
  }
  return out;
}

std::vector<std::string> splitPath(const std::string& path) {
  std::vector<std::string> parts;
  size_t i = 0;
  while (i < path.size()) {
    if (path[i] == '/') {
      ++i;
      continue;
    }
    const size_t j = path.find('/', i);
    parts.push_back(percentDecode(path.substr(i, j == std::string::npos ? std::string::npos : j - i)));
    if (j == std::string::npos) break;
    i = j;
  }
  return parts;
}

std::string queryValue(const std::string& query, const std::string& key) {
  std::istringstream in(query);
  std::string kv;
  while (std::getline(in, kv, '&')) {
    const size_t eq = kv.find('=');
    if (percentDecode(kv.substr(0, eq)) == key) return eq == std::string::npos ? "" : percentDecode(kv.substr(eq + 1));
  }
  return {};
}

long queryInteger(const std::string& query, const std::string& key, long fallback, long lo, long hi) {
  const std::string text = queryValue(query, key);
  if (text.empty()) return fallback;
  char* end = nullptr;
  errno = 0;
  const long v = std::strtol(text.c_str(), &end, 10);
  if (errno != 0 || end == text.c_str() || *end != '\0' || v < lo || v > hi)
    throw ApiError(400, "query \"" + key + "\" must be an integer in [" + std::to_string(lo) + ", " +
                            std::to_string(hi) + "], got \"" + text.substr(0, 40) + "\"",
                   key);
  return v;
}

void checkName(const std::string& name, const std::string& what) {
  if (!isValidTemplateName(name))
    throw ApiError(400, what + " name \"" + name.substr(0, 80) +
                            "\" is invalid: names are 1 to 64 characters from A-Z a-z 0-9 _ -",
                   what);
}

json parseBody(const HttpRequest& req, bool required) {
  if (req.body.empty()) {
    if (required) throw ApiError(400, "the request needs a JSON body");
    return json::object();
  }
  return parseJsonLimited(req.body);
}

const json& requireObject(const json& body) {
  if (!body.is_object()) throw ApiError(400, std::string("the body must be a JSON object, not ") + body.type_name());
  return body;
}

void onlyKeys(const json& body, const std::vector<std::string>& keys) {
  asBadRequest([&] { json_access::checkKeys(body, "", keys); });
}

std::string bodyString(const json& body, const std::string& key, std::optional<std::string> fallback) {
  return asBadRequest([&] { return json_access::stringField(body, "", key, fallback); });
}

int64_t bodyInteger(const json& body, const std::string& key, std::optional<int64_t> fallback, const Bounds& bounds) {
  return asBadRequest([&] { return json_access::integerField(body, "", key, fallback, bounds); });
}

double bodyNumber(const json& body, const std::string& key, std::optional<double> fallback, const Bounds& bounds) {
  return asBadRequest([&] { return json_access::numberField(body, "", key, fallback, bounds); });
}

bool bodyBool(const json& body, const std::string& key, bool fallback) {
  return asBadRequest([&] { return json_access::boolField(body, "", key, fallback); });
}

json instancesOf(const json& scene) {
  return scene.contains("instances") && scene["instances"].is_array() ? scene["instances"] : json::array();
}

}  // namespace fc::service::rest
