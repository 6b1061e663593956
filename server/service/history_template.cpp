// Templates recorded from a session's history: see history_template.h.
#include "service/history_template.h"

#include "io/recipe.h"

#include <cmath>
#include <stdexcept>

namespace fc::service {

void checkTemplateRequest(int dimension, TemplateDatabase& db, const std::string& name,
                          const std::vector<double>& regionMin, const std::vector<double>& regionMax, int firstFrame,
                          int lastFrame, bool force) {
  checkTemplateName(name);
  for (const auto* r : {&regionMin, &regionMax}) {
    const char* key = r == &regionMin ? "region_min" : "region_max";
    if (r->size() != size_t(dimension))
      throw std::invalid_argument(std::string(key) + " must have " + std::to_string(dimension) +
                                  " values (dimension " + std::to_string(dimension) + "), got " +
                                  std::to_string(r->size()));
    for (int d = 0; d < dimension; ++d)
      if (!std::isfinite((*r)[size_t(d)]))
        throw std::invalid_argument(std::string(key) + "[" + std::to_string(d) + "] must be finite");
  }
  for (int d = 0; d < dimension; ++d)
    if (!(regionMin[size_t(d)] < regionMax[size_t(d)]))
      throw std::invalid_argument("region_max[" + std::to_string(d) + "] must be greater than region_min[" +
                                  std::to_string(d) + "]");
  if (firstFrame > lastFrame)
    throw std::invalid_argument("the first frame (" + std::to_string(firstFrame) + ") is after the last frame (" +
                                std::to_string(lastFrame) + ")");
  if (!force && db.contains(name))
    throw DatabaseError("template '" + name + "' already exists ('" + db.pathFor(name) +
                        "'); use force to overwrite it");
}

template <int D>
TemplateEntry recordTemplateFromFrames(TemplateDatabase& db, const std::string& name,
                                       const std::vector<double>& regionMin, const std::vector<double>& regionMax,
                                       const std::vector<FramePtr>& frames, const RecordedScene& info,
                                       std::string recipe, std::string createdBy, bool force) {
  if (frames.empty()) throw std::invalid_argument("no recorded frame to make a template of");
  // A frame-rate edit in or after the range: the frames are not 1/frameRate apart.
  const double dt = 1 / info.frameRate;
  for (size_t k = 1; k < frames.size(); ++k)
    if (std::abs(frames[k]->time - frames[k - 1]->time - dt) > 1e-3 * dt)
      throw std::invalid_argument("frames " + std::to_string(frames.front()->frame) + " to " +
                                  std::to_string(frames.back()->frame) + " were not all recorded at the scene's frame rate (" +
                                  std::to_string(info.frameRate) + " frames/s): a settings edit changed it");

  Template<D> tpl;
  TemplateHeader& h = tpl.header;
  h.name = name;
  h.dimension = D;
  h.frameRate = info.frameRate;
  h.particleRadius = info.particleRadius;
  h.supportRadius = info.supportRadius;
  h.restDensity = double(info.phases.at(0).restDensity);  // as the recipe capture
  h.regionMin = regionMin;
  h.regionMax = regionMax;
  h.recipe = std::move(recipe);
  h.createdBy = std::move(createdBy);
  templateFramesOf<D>(frames, regionMin, regionMax, info.phaseMass, tpl.frames);
  size_t captured = 0;
  for (const auto& f : tpl.frames) captured += f.size();
  if (captured == 0)
    throw std::invalid_argument("no liquid particle lies in the region (region_min, region_max) in frames " +
                                std::to_string(frames.front()->frame) + " to " + std::to_string(frames.back()->frame));
  publishTemplate<D>(db.directory(), tpl, force, "force");
  return db.entry(name);
}

template TemplateEntry recordTemplateFromFrames<2>(TemplateDatabase&, const std::string&, const std::vector<double>&,
                                                   const std::vector<double>&, const std::vector<FramePtr>&,
                                                   const RecordedScene&, std::string, std::string, bool);
template TemplateEntry recordTemplateFromFrames<3>(TemplateDatabase&, const std::string&, const std::vector<double>&,
                                                   const std::vector<double>&, const std::vector<FramePtr>&,
                                                   const RecordedScene&, std::string, std::string, bool);

}  // namespace fc::service
