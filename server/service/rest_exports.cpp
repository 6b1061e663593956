#include "service/rest_api.h"

// Exports of a session's history: POST /api/sessions/{id}/export writes
// NAME.h5 + NAME.xdmf to the exports directory (service/history_export.h),
// GET /api/exports/{file} serves them.
#include "service/rest_support.h"

#include <filesystem>
#include <fstream>
#include <iterator>

namespace fc::service {

using namespace rest;
namespace fs = std::filesystem;

HttpResponse ServiceHub::exportFrames(const HttpRequest& req, const Params& p) {
  auto s = requireSession(p[0]);
  const json body = requireObject(parseBody(req));
  onlyKeys(body, {"name", "first_frame", "last_frame", "force"});
  const std::string name = bodyString(body, "name");
  checkName(name, "export");
  // -1: the oldest / the newest frame kept.
  const int first = int(bodyInteger(body, "first_frame", -1, {0, INT32_MAX}));
  const int last = int(bodyInteger(body, "last_frame", -1, {0, INT32_MAX}));
  const bool force = bodyBool(body, "force", false);
  const fs::path h5 = fs::path(options_.exportsDir) / (name + ".h5");
  std::lock_guard lk(fileMutex_);
  if (!force) {
    const fs::path xdmf = fs::path(options_.exportsDir) / (name + ".xdmf");
    const bool haveH5 = fs::exists(h5), haveXdmf = fs::exists(xdmf);
    if (haveH5 || haveXdmf)
      throw ApiError(409, "export \"" + name + "\" already exists in " + options_.exportsDir + " (" +
                              (haveH5 && haveXdmf ? name + ".h5 and " + name + ".xdmf"
                                                  : (haveH5 ? name + ".h5" : name + ".xdmf") + " alone") +
                              "; send \"force\": true to replace it)",
                     "name");
  }
  std::error_code ec;
  fs::create_directories(options_.exportsDir, ec);
  HistoryExport e;
  try {
    e = s->exportHistory(h5.string(), first, last);
  } catch (const StaleFramesError& err) {
    throw ApiError(409, err.what(), "first_frame");
  } catch (const std::invalid_argument& err) {
    throw ApiError(422, err.what(), "first_frame");
  }
  return jsonResponse({{"name", name},
                       {"h5", name + ".h5"},
                       {"xdmf", name + ".xdmf"},
                       {"frames", e.frames},
                       {"particle_rows", e.particleRows},
                       {"bytes", e.bytes}},
                      201);
}

HttpResponse ServiceHub::getExport(const HttpRequest&, const Params& p) {
  const std::string& file = p[0];
  const size_t dot = file.rfind('.');
  const std::string stem = dot == std::string::npos ? file : file.substr(0, dot);
  const std::string ext = dot == std::string::npos ? "" : file.substr(dot);
  if (ext != ".h5" && ext != ".xdmf")
    throw ApiError(400, "export file \"" + file.substr(0, 80) + "\" must be NAME.h5 or NAME.xdmf", "file");
  checkName(stem, "export");
  const fs::path path = fs::path(options_.exportsDir) / file;
  std::ifstream in(path, std::ios::binary);
  if (!in) throw ApiError(404, "no export file \"" + file + "\" in " + options_.exportsDir, "file");
  HttpResponse r;
  r.contentType = ext == ".h5" ? "application/x-hdf5" : "application/xml";
  r.body.assign(std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>());
  r.headers.emplace_back("Content-Disposition", "attachment; filename=\"" + file + "\"");
  return r;
}

}  // namespace fc::service
