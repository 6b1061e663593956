#pragma once
// Scene files: JSON <-> SimulationSetup, with validation that names the key
// path of every error. The format is documented in scenes/README.md.
#include "control/instance.h"
#include "io/json_access.h"
#include "sph/setup.h"
#include <nlohmann/json.hpp>
#include <stdexcept>
#include <string>
#include <vector>

namespace fc {

// An invalid scene: a JSON value error (io/json_access.h) whose `path`
// locates the offending value the way a user would type it
// (`fluid_blocks[1].min[0]`, `solver.density_tolerance_pct`); it is empty for
// file-level errors (missing file, malformed JSON), whose message names the
// file instead. what() is "<path>: <message>", or just the message when the
// path is empty.
using SceneError = JsonValueError;

// Parses scene JSON text. Besides syntax errors (reported with line and
// column) this rejects duplicate object keys, which plain JSON parsers
// resolve silently by keeping the last one. `origin` names the source (a file
// name) in error messages.
// Nesting deeper than kMaxSceneDepth is an error (no scene needs more than a
// handful of levels; deep values would exhaust the stack when copied).
inline constexpr int kMaxSceneDepth = 64;
inline constexpr size_t kMaxSceneFileBytes = size_t(64) << 20;
nlohmann::json parseSceneText(const std::string& text, const std::string& origin = "scene");

// Reads and parses a scene file (see parseSceneText; anything but a JSON
// object is an error naming the file), then resolves the
// files it names (resolveSceneFilePaths).
nlohmann::json loadSceneJson(const std::string& file);

// Mesh obstacles name their OBJ file relative to the scene file's directory:
// this rewrites every relative `obstacles[i].file` of a "mesh" obstacle in
// `scene` to an absolute path, from the directory of `sceneFile`. JSON that
// comes from no file (parseScene on an inline scene, a REST request) keeps
// its paths as written: absolute, or relative to the current directory.
// Anything malformed is left for parseScene to report.
void resolveSceneFilePaths(nlohmann::json& scene, const std::string& sceneFile);

// The scene at one of its named resolutions ("scales": {"paper": {...}}):
// a copy with that scale's particle_radius (and max_particles, if it sets
// one). An unknown name is a SceneError at "scales.NAME" listing the known
// ones; the values are checked by parseScene.
nlohmann::json applySceneScale(const nlohmann::json& scene, const std::string& scale);

// Where the templates of a scene's scale live: DIR/NAME (templates recorded
// at that scale's resolution, `flowclip record --scale NAME`), or DIR/FOLDER
// where the scale names its own ("templates": FOLDER: a scene that plays a
// recipe at another resolution than the recipe's own scale of that name).
std::string scaledTemplatesDir(const std::string& dir, const nlohmann::json& scene, const std::string& scale);

// The scene's "dimension" (2 or 3), so callers can pick parseScene<2> or <3>.
int sceneDimension(const nlohmann::json& scene);

// Validates a scene and builds its setup. registerBuiltinSolversAndEffects()
// is called first, so solver and effect names resolve. A positive
// particleRadiusOverride replaces the scene's particle_radius (resolution
// studies, interactive previews); every check, including max_particles, then
// applies to the overridden radius.
template <int D>
SimulationSetup<D> parseScene(const nlohmann::json& scene, double particleRadiusOverride = 0);

// The inverse of parseScene: every key is written, defaults included, so the
// result documents the full setup and parses back to an identical one.
template <int D>
nlohmann::json sceneToJson(const SimulationSetup<D>& setup);

// The control part of a scene (paper §3.5): the "control" settings object and
// the "instances" array (format in scenes/README.md). parseScene accepts both
// keys without reading them; parseSceneControl validates them, naming the key
// path of every error (`instances[1].transform[0].scale[0]`). Templates are
// not looked up here (see io/instance_binding.h): an instance's time map is
// checked against its template's duration only at bind time.
template <int D>
struct SceneControl {
  std::vector<InstanceSpec<D>> instances;  // every name set and unique
  ControlSettings settings = controlSettingsTable().defaults();  // the scene's "control"
};

// `phases` are the scene's (SimulationSetup::phases): instances name theirs.
template <int D>
SceneControl<D> parseSceneControl(const nlohmann::json& scene, const std::vector<Phase>& phases);

// {"control": {...}, "instances": [...]} with every key written (defaults
// included; crop_end only when set), which parseSceneControl reads back to an
// identical SceneControl. Merge it into a scene written by sceneToJson.
template <int D>
nlohmann::json sceneControlToJson(const SceneControl<D>& control, const std::vector<Phase>& phases);

}  // namespace fc
