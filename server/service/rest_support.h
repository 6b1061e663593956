#pragma once
// What the REST handler files (rest_*.cpp, one per resource) share: JSON
// responses, path and query decoding, the name rule, request bodies and
// their fields. Internal to the REST API; service/rest_api.h is its interface.
#include "io/json_access.h"
#include "service/rest_api.h"

#include <nlohmann/json.hpp>

#include <cstdint>
#include <optional>
#include <string>
#include <vector>

namespace fc::service::rest {

using json = nlohmann::json;
using json_access::Bounds;
using json_access::kRequired;

HttpResponse jsonResponse(const json& j, int status = 200);

// ---- URLs -------------------------------------------------------------------------------

std::string percentDecode(const std::string& s);
// The non-empty segments of a path, each percent-decoded.
std::vector<std::string> splitPath(const std::string& path);
// The decoded value of `key` in a query string; "" when absent.
std::string queryValue(const std::string& query, const std::string& key);
// An integer query parameter in [lo, hi]; `fallback` when absent. 400 otherwise.
long queryInteger(const std::string& query, const std::string& key, long fallback, long lo, long hi);

// Names in URLs and bodies share the template database's rule, so no name
// can reach outside its directory ("..", "/", "%2F" are all refused): 400
// naming `what` ("template", "scene", ...).
void checkName(const std::string& name, const std::string& what);

// ---- bodies -----------------------------------------------------------------------------

// The body as JSON (parseJsonLimited); an empty body is 400 when `required`,
// else an empty object.
json parseBody(const HttpRequest& req, bool required = true);
// 400 unless the body is a JSON object.
const json& requireObject(const json& body);

// Runs `read`, which reads a body with io/json_access.h: a bad value is
// answered 400 with its key path (the same error from a scene is 422).
template <class Read>
auto asBadRequest(Read&& read) -> decltype(read()) {
  try {
    return read();
  } catch (const JsonValueError& e) {
    throw ApiError(400, e.what(), e.path);
  }
}

// Fields of a body object (json_access's field readers at the root path),
// each a 400 naming its key when wrong.
void onlyKeys(const json& body, const std::vector<std::string>& keys);
std::string bodyString(const json& body, const std::string& key, std::optional<std::string> fallback = kRequired);
int64_t bodyInteger(const json& body, const std::string& key, std::optional<int64_t> fallback, const Bounds& bounds);
double bodyNumber(const json& body, const std::string& key, std::optional<double> fallback, const Bounds& bounds);
bool bodyBool(const json& body, const std::string& key, bool fallback);

// ---- scenes -----------------------------------------------------------------------------

// The scene's "instances" array (empty when it has none).
json instancesOf(const json& scene);

}  // namespace fc::service::rest
