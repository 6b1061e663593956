#pragma once
// Recording recipes (templates/recipes/*.json) and the recorder.
//
// A recipe is a scene file (scenes/README.md) plus one "capture" object:
//   "capture": {
//     "name":   "drop2d",                      // template name, [A-Za-z0-9_-]{1,64}
//     "region": {"min": [..], "max": [..]},    // capture box, D numbers each, min < max
//     "frames": N        (integer >= 1)        // exactly one of frames / seconds
//     "seconds": S       (number > 0)          //   frames = round(S * frame_rate) + 1
//     "start": T         (number >= 0, optional, default 0) // simulated seconds before frame 0
//   }
// Template frame 0 is the simulation state at time `start` (rounded to whole
// frames), frame k the state k frames later. At every template frame all
// liquid particles (kind Liquid) whose centre lies inside the closed region
// box are captured with position, velocity, mass and phase, in the recipe's
// world coordinates (the region is stored in the header).
#include "control/template.h"
#include "io/scene.h"
#include "sph/simulation.h"

#include <nlohmann/json.hpp>
#include <functional>
#include <optional>
#include <string>
#include <vector>

namespace fc {

struct CaptureSpec {
  std::string name;
  std::vector<double> regionMin, regionMax;
  std::optional<int> frames;
  std::optional<double> seconds;
  double start = 0;
};

struct Recipe {
  nlohmann::json scene;   // the recipe without "capture": a scene for parseScene
  CaptureSpec capture;
  int dimension = 0;
  std::string text;       // the recipe's JSON text, stored in the template header
};

// Splits and validates a recipe. Errors are SceneError with key paths
// ("capture.region.min[1]", "capture": missing), and every scene error
// parseScene would report. `text` is stored as the header's recipe (the
// JSON is dumped when empty).
Recipe parseRecipe(const nlohmann::json& recipe, const std::string& text = "");
// Reads a recipe file (SceneError naming the file on I/O or syntax errors).
Recipe loadRecipe(const std::string& file);

struct RecordProgress {
  int frame = 0;            // template frames captured so far
  int frames = 0;           // template frames in total
  int simFrame = 0;         // simulation frames advanced
  size_t captured = 0;      // particles captured in the last frame
  FrameStats stats;         // of the last simulation frame (frame 0 before any step: default)
};

struct RecordOptions {
  std::string templatesDir = "templates";
  bool force = false;                 // overwrite an existing template
  double particleRadiusOverride = 0;  // > 0: replaces the scene's particle radius
  // Called after every captured frame; returning false aborts the recording
  // (nothing is written, recordRecipe throws RecordAborted).
  std::function<bool(const RecordProgress&)> progress;
  bool keepTemplate = false;          // fill RecordResult::tpl2/tpl3 with what was written
};

struct RecordResult {
  std::string path;                   // the written file
  std::string name;
  int dimension = 0;
  size_t frames = 0;
  size_t particleFrames = 0;
  std::vector<size_t> capturedPerFrame;
  double wallSeconds = 0;             // simulation + capture
  double writeSeconds = 0;
  std::optional<Template<2>> tpl2;    // when keepTemplate
  std::optional<Template<3>> tpl3;
};

struct RecordAborted : std::runtime_error {
  using std::runtime_error::runtime_error;
};

// Simulates the recipe and returns the captured template (nothing written).
// Throws SceneError (recipe), std::invalid_argument (simulation setup),
// std::runtime_error (non-finite state: the simulation blew up),
// RecordAborted (progress returned false).
template <int D>
Template<D> captureTemplate(const Recipe& recipe, const RecordOptions& options = {});

// Records the recipe into options.templatesDir/NAME.h5 (atomically). Throws
// DatabaseError before simulating if the template exists and !force (the
// existing file is untouched), plus everything captureTemplate throws and
// TemplateError on write failures.
RecordResult recordRecipe(const Recipe& recipe, const RecordOptions& options = {});

}  // namespace fc
