#include "service/rest_api.h"

// /api/templates: the template database (list, details, delete, library
// previews), and POST /api/sessions/{id}/templates, which records a template
// from a session's frames.
#include "io/template_file.h"
#include "service/rest_support.h"
#include "sph/limits.h"

#include <algorithm>
#include <cmath>
#include <filesystem>

namespace fc::service {

using namespace rest;

namespace {

json templateEntryJson(const TemplateEntry& e) {
  json j = {{"name", e.name}};
  if (!e.error.empty()) {
    j["error"] = e.error;
    return j;
  }
  j.update({{"dimension", e.dimension},
            {"frames", e.frames},
            {"frame_rate", e.frameRate},
            {"duration", e.duration},
            {"avg_particles", e.avgParticles},
            {"region_min", e.regionMin},
            {"region_max", e.regionMax},
            {"bytes", e.bytesOnDisk}});
  return j;
}

// Positions of one template frame for a library thumbnail: every k-th
// particle so that at most maxPoints remain, rounded to 0.1 mm.
template <int D>
json previewJson(const TemplateHeader& header, size_t frames, const TemplateFrame<D>& f, long frame, long maxPoints) {
  const size_t n = f.size();
  const size_t stride = std::max<size_t>(1, (n + size_t(maxPoints) - 1) / size_t(maxPoints));
  json pos = json::array();
  for (size_t i = 0; i < n; i += stride)
    for (int d = 0; d < D; ++d) pos.push_back(std::round(double(f.x[i][d]) * 1e4) / 1e4);
  return {{"name", header.name},
          {"dimension", D},
          {"frame", frame},
          {"frames", frames},
          {"time", double(frame) / header.frameRate},
          {"particles", n},
          {"stride", stride},
          {"region_min", header.regionMin},
          {"region_max", header.regionMax},
          {"positions", pos}};
}

template <int D>
std::shared_ptr<const void> openPreview(const std::string& path, bool streamed) {
  if (streamed) return std::make_shared<const TemplateStream<D>>(path);
  return std::make_shared<const Template<D>>(readTemplate<D>(path));
}

template <int D>
size_t previewFrames(const std::shared_ptr<const void>& tpl, bool streamed) {
  return streamed ? static_cast<const TemplateStream<D>*>(tpl.get())->frameCount()
                  : static_cast<const Template<D>*>(tpl.get())->frameCount();
}

template <int D>
json previewOf(const std::shared_ptr<const void>& tpl, bool streamed, long frame, long maxPoints) {
  if (!streamed) {
    const auto& t = *static_cast<const Template<D>*>(tpl.get());
    return previewJson<D>(t.header, t.frameCount(), t.frames[size_t(frame)], frame, maxPoints);
  }
  const auto& s = *static_cast<const TemplateStream<D>*>(tpl.get());
  return previewJson<D>(s.header(), s.frameCount(), s.readFrame(size_t(frame)), frame, maxPoints);
}

}  // namespace

HttpResponse ServiceHub::listTemplates(const HttpRequest&, const Params&) {
  json list = json::array();
  for (const TemplateEntry& e : database_.list()) list.push_back(templateEntryJson(e));
  return jsonResponse({{"templates", list}});
}

HttpResponse ServiceHub::getTemplate(const HttpRequest&, const Params& p) {
  checkName(p[0], "template");
  if (!database_.contains(p[0])) throw ApiError(404, "no template \"" + p[0] + "\" in " + database_.directory(), "name");
  return jsonResponse(templateEntryJson(database_.entry(p[0])));
}

HttpResponse ServiceHub::deleteTemplate(const HttpRequest&, const Params& p) {
  checkName(p[0], "template");
  if (!database_.contains(p[0])) throw ApiError(404, "no template \"" + p[0] + "\" in " + database_.directory(), "name");
  // A session's scene that instances it could not be reset or saved and re-opened.
  for (const auto& s : allSessions())
    for (const json& inst : instancesOf(s->sceneJson()))
      if (inst.value("template", "") == p[0])
        throw ApiError(409, "template \"" + p[0] + "\" is in use by session " + s->id() + " (instance \"" +
                                inst.value("name", "") + "\"); remove the instance or delete the session first",
                       "name");
  database_.remove(p[0]);
  {
    std::lock_guard<std::mutex> lock(previewMutex_);
    previews_.erase(p[0]);
  }
  return jsonResponse({{"deleted", p[0]}});
}

HttpResponse ServiceHub::templatePreview(const HttpRequest& req, const Params& p) {
  checkName(p[0], "template");
  if (!database_.contains(p[0])) throw ApiError(404, "no template \"" + p[0] + "\" in " + database_.directory(), "name");
  const std::string path = database_.pathFor(p[0]);
  std::error_code ec;
  const uint64_t size = std::filesystem::file_size(path, ec);
  const int64_t mtime = ec ? 0 : int64_t(std::filesystem::last_write_time(path, ec).time_since_epoch().count());
  PreviewSource src;
  {
    std::lock_guard<std::mutex> lock(previewMutex_);
    auto it = previews_.find(p[0]);
    if (it != previews_.end() && it->second.size == size && it->second.mtime == mtime) src = it->second;
  }
  if (!src.tpl) {
    try {
      const TemplateHeader header = readTemplateHeader(path);
      src.dimension = header.dimension;
      src.streamed = startsWithChecksumBlock(path);
      src.tpl = header.dimension == 2 ? openPreview<2>(path, src.streamed) : openPreview<3>(path, src.streamed);
    } catch (const TemplateError& e) {
      throw ApiError(422, e.what(), "name");
    }
    src.size = size;
    src.mtime = mtime;
    std::lock_guard<std::mutex> lock(previewMutex_);
    // A few decoded templates at most (a large 3D one holds tens of MB).
    if (previews_.size() >= kPreviewCacheSize && !previews_.count(p[0])) previews_.erase(previews_.begin());
    previews_[p[0]] = src;
  }
  const size_t frames =
      src.dimension == 2 ? previewFrames<2>(src.tpl, src.streamed) : previewFrames<3>(src.tpl, src.streamed);
  if (frames == 0) throw ApiError(422, "template \"" + p[0] + "\" has no frames", "name");
  const long frame = queryInteger(req.query, "frame", long(frames / 2), 0, long(frames) - 1);
  const long maxPoints = queryInteger(req.query, "max", 2000, 1, 100000);
  json out;
  try {
    out = src.dimension == 2 ? previewOf<2>(src.tpl, src.streamed, frame, maxPoints)
                             : previewOf<3>(src.tpl, src.streamed, frame, maxPoints);
  } catch (const TemplateError& e) {
    throw ApiError(422, e.what(), "name");
  }
  return jsonResponse(out);
}

HttpResponse ServiceHub::recordTemplate(const HttpRequest& req, const Params& p) {
  auto s = requireSession(p[0]);
  const json body = requireObject(parseBody(req));
  onlyKeys(body, {"name", "region_min", "region_max", "first_frame", "last_frame", "force"});
  const std::string name = bodyString(body, "name");
  checkName(name, "template");
  // A corner: D coordinates, each in the physical range (sph/limits.h).
  const int dim = s->dimension();
  auto corner = [&](const std::string& key) {
    return asBadRequest([&] {
      const json& v = json_access::required(body, "", key, "a corner of the capture region, m");
      json_access::expectType(v.is_array() && v.size() == size_t(dim), v, key,
                              dim == 2 ? "an array of 2 numbers" : "an array of 3 numbers");
      std::vector<double> out;
      for (size_t d = 0; d < v.size(); ++d) {
        const std::string at = json_access::indexPath(key, d);
        out.push_back(json_access::checkBounds(json_access::getNumber(v[d], at), at,
                                               json_access::boundsOf(limits::kCoordinate, "physical")));
      }
      return out;
    });
  };
  const std::vector<double> lo = corner("region_min"), hi = corner("region_max");
  const int first = int(bodyInteger(body, "first_frame", kRequired, {0, INT32_MAX}));
  const int last = int(bodyInteger(body, "last_frame", kRequired, {0, INT32_MAX}));
  const bool force = bodyBool(body, "force", false);
  if (!force && database_.contains(name))
    throw ApiError(409, "template \"" + name + "\" already exists (send \"force\": true to replace it)", "name");
  try {
    const TemplateEntry e = s->recordTemplate(database_, name, lo, hi, first, last, force);
    return jsonResponse(templateEntryJson(e), 201);
  } catch (const DatabaseError& e) {
    throw ApiError(409, e.what(), "name");
  } catch (const StaleFramesError& e) {
    throw ApiError(409, e.what(), "first_frame");
  }
}

}  // namespace fc::service
