#pragma once
// Recording recipes (templates/recipes/*.json) and the recorder.
//
// A recipe is a scene file (scenes/README.md) plus "capture": one capture
// object, or an array of them (one simulation records several templates):
//   "capture": {
//     "name":   "drop2d",                      // template name, [A-Za-z0-9_-]{1,64}
//     "region": {"min": [..], "max": [..]},    // capture box, D numbers each, min < max
//     "frames": N        (integer >= 1)        // exactly one of frames / seconds
//     "seconds": S       (number > 0)          //   frames = round(S * frame_rate) + 1
//     "start": T         (number >= 0, optional, default 0) // simulated seconds before frame 0
//   }
//   "capture": [{"name": "a", ...}, {"name": "b", ...}]   // names unique within the recipe
// Each capture follows its own rules: its template frame 0 is the simulation
// state at time `start` (rounded to whole frames), frame k the state k frames
// later. At every template frame all liquid particles (kind Liquid) whose
// centre lies inside the closed region box are captured with position,
// velocity, mass and phase, in the recipe's world coordinates (the region is
// stored in the header). The simulation runs until the last capture ends.
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
  std::vector<CaptureSpec> captures;  // in recipe order; at least one, names unique
  int dimension = 0;
  std::string text;       // the recipe's JSON text, stored in the template header
};

// Splits and validates a recipe. Errors are SceneError with key paths
// ("capture.region.min[1]", "capture[2].region.min[1]", "capture[1].name"
// for a duplicate name, "capture": missing), and every scene error
// parseScene would report. `text` is stored as the header's recipe (the
// JSON is dumped when empty).
Recipe parseRecipe(const nlohmann::json& recipe, const std::string& text = "");
// Reads a recipe file (SceneError naming the file on I/O or syntax errors).
Recipe loadRecipe(const std::string& file);

// The simulation frames recording the recipe advances (RecordProgress::
// simFrames): to the last capture's last frame at the scene's frame rate.
int recipeSimulationFrames(const Recipe& recipe);

// Progress counts capture frames: the simulation frames from the first
// capture's frame 0 to the last capture's last frame (with one capture, its
// template frames).
struct RecordProgress {
  int frame = 0;            // capture frames done so far
  int frames = 0;           // capture frames in total
  int simFrame = 0;         // simulation frames advanced
  int simFrames = 0;        // simulation frames to advance in all (to the last capture's last frame)
  size_t captured = 0;      // particles captured in the last frame (summed over the captures)
  FrameStats stats;         // of the last simulation frame (frame 0 before any step: default)
};

struct RecordOptions {
  std::string templatesDir = "templates";
  bool force = false;                 // overwrite an existing template
  double particleRadiusOverride = 0;  // > 0: replaces the scene's particle radius
  // Called after every captured frame; returning false aborts the recording
  // (nothing is written, recordRecipe throws RecordAborted).
  std::function<bool(const RecordProgress&)> progress;
  // Called after every simulation frame, the frames before the first
  // capture included (where `progress` is not), so that a caller can follow
  // and abort a long pre-roll; returning false aborts as `progress` does.
  std::function<bool(const RecordProgress&)> simulationProgress;
  bool keepTemplate = false;          // fill RecordedTemplate::tpl2/tpl3 with what was written
};

struct RecordedTemplate {
  std::string path;                   // the written file
  std::string name;
  size_t frames = 0;
  size_t particleFrames = 0;
  std::vector<size_t> capturedPerFrame;
  double writeSeconds = 0;
  std::optional<Template<2>> tpl2;    // when keepTemplate
  std::optional<Template<3>> tpl3;
};

struct RecordResult {
  int dimension = 0;
  std::vector<RecordedTemplate> templates;  // one per capture, in recipe order
  double wallSeconds = 0;             // simulation + capture (shared by all templates)
  double writeSeconds = 0;            // all templates
};

struct RecordAborted : std::runtime_error {
  using std::runtime_error::runtime_error;
};

// Simulates the recipe once and returns one template per capture, in recipe
// order (nothing written). Throws SceneError (recipe), std::invalid_argument
// (simulation setup), std::runtime_error (non-finite state: the simulation
// blew up), RecordAborted (progress returned false).
template <int D>
std::vector<Template<D>> captureTemplates(const Recipe& recipe, const RecordOptions& options = {});

// Records every capture of the recipe into options.templatesDir/NAME.h5, all
// or nothing: each template is written to a hidden temporary file next to
// its final name, and only when all are written are they moved to their
// names (without force, by a link that fails if the name has appeared
// meanwhile, so no existing file is replaced). If anything fails, every new
// file is removed and every replaced one put back; after a crash,
// recoverPublishing(templatesDir) does it (io/staged_files.h). Throws DatabaseError
// before simulating if a template exists and !force (existing files are
// untouched), plus everything captureTemplates throws and TemplateError on
// write failures.
RecordResult recordRecipe(const Recipe& recipe, const RecordOptions& options = {});

// Writes one template made elsewhere (a session's history) as
// templatesDir/NAME.h5, NAME = tpl.header.name, the way recordRecipe writes
// each of its templates: to a hidden temporary file, then moved to its name
// (io/staged_files.h). Without force, throws DatabaseError (its message ends
// "use <forceHint> to overwrite it") if the template exists, checked before
// writing and again, race-free, when moving. Throws DatabaseError for an
// invalid name or an uncreatable directory and TemplateError on write
// failures; nothing is left behind. Returns the path written.
template <int D>
std::string publishTemplate(const std::string& templatesDir, const Template<D>& tpl, bool force,
                            const std::string& forceHint = "--force");

}  // namespace fc
