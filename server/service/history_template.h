#pragma once
// Templates recorded from a session's replay history: a region of the
// recorded frames over a frame range becomes a template of the database,
// published all-or-nothing (io/recipe.h publishTemplate).
#include "io/scene.h"
#include "io/template_database.h"
#include "service/frame_snapshot.h"

#include <string>
#include <vector>

namespace fc::service {

// What a template needs to know of the scene its frames come from.
struct RecordedScene {
  std::string sceneName;
  double particleRadius = 0, supportRadius = 0, frameRate = 0;
  std::vector<Phase> phases;
  std::vector<Real> phaseMass;  // Simulation::particleMass per phase
  std::vector<double> domainMin, domainMax;
};

// Checks a request before any frame is gathered: the name, the region
// (`dimension` finite values each, min < max), the range, and an existing
// template of that name without `force`. Throws std::invalid_argument or
// DatabaseError saying what is wrong.
void checkTemplateRequest(int dimension, TemplateDatabase& db, const std::string& name,
                          const std::vector<double>& regionMin, const std::vector<double>& regionMax, int firstFrame,
                          int lastFrame, bool force);

// The template of `frames` (consecutive recorded frames, oldest first): the
// liquid particles inside [regionMin, regionMax] in each, written into the
// database. Throws std::invalid_argument when the frames were not recorded
// at one frame rate or the region holds no liquid.
template <int D>
TemplateEntry recordTemplateFromFrames(TemplateDatabase& db, const std::string& name,
                                       const std::vector<double>& regionMin, const std::vector<double>& regionMax,
                                       const std::vector<FramePtr>& frames, const RecordedScene& info,
                                       std::string recipe, std::string createdBy, bool force);

}  // namespace fc::service
