// Fuzz target: scene files (io/scene.h), validated the way `flowclip run`
// validates one (app/run_command.cpp) without simulating: the bytes are a
// scene file's text -> parseSceneText -> (copied and serialised, as the
// server's scene routes do) -> (JSON object) -> resolveSceneFilePaths ->
// sceneDimension -> parseScene<D> -> parseSceneControl<D>, then the same for
// each of its named resolutions (applySceneScale, `--scale NAME`).
//
// Documented outcome for bad input: fc::SceneError. Anything else escaping
// is a finding (libFuzzer reports the std::terminate abort). For a valid
// scene the round trip scene.h promises is checked: sceneToJson +
// sceneControlToJson parse back to a setup that writes the identical JSON.
//
// No Simulation is built (grids and particles could take gigabytes); mesh
// obstacles are, as parseScene builds their signed-distance grid (bounded by
// MeshGridTooLarge). Relative mesh paths resolve from the repository's
// scenes/ directory, so the seed scene naming meshes/ramp.obj reaches the
// mesh code (an obstacle file must end in .obj: no device can be opened).
#include "fuzz_support.h"
#include "io/scene.h"
#include <filesystem>

#include <nlohmann/json.hpp>

#include <cstdint>
#include <string>

namespace {

using nlohmann::json;

const std::string& sceneOrigin() {
  static const std::string origin =
      fc::fuzz::env("FLOWCLIP_FUZZ_SCENE_DIR", std::string(FLOWCLIP_SOURCE_DIR) + "/scenes") + "/fuzz.json";
  return origin;
}

template <int D>
json writeScene(const fc::SimulationSetup<D>& setup, const fc::SceneControl<D>& control) {
  json j = fc::sceneToJson<D>(setup);
  j.update(fc::sceneControlToJson<D>(control, setup.phases));
  return j;
}

template <int D>
void validate(const json& scene) {
  const fc::SimulationSetup<D> setup = fc::parseScene<D>(scene);
  // parseSceneControl's one std::invalid_argument is for a setup without
  // phases, which parseScene never returns.
  const fc::SceneControl<D> control = fc::parseSceneControl<D>(scene, setup.phases);

  // Round trip: what the scene writes must read back, identically.
  const json written = writeScene<D>(setup, control);
  json rewritten;
  try {
    const fc::SimulationSetup<D> again = fc::parseScene<D>(written);
    rewritten = writeScene<D>(again, fc::parseSceneControl<D>(written, again.phases));
  } catch (const fc::SceneError& e) {
    fc::fuzz::fail(__FILE__, __LINE__, "sceneToJson's output is rejected by parseScene",
                   std::string(e.what()) + "\n" + written.dump(1, ' ', false, json::error_handler_t::replace));
  }
  FUZZ_CHECK(rewritten == written, "written:\n" + written.dump(-1, ' ', false, json::error_handler_t::replace) +
                                       "\nread back and written again:\n" +
                                       rewritten.dump(-1, ' ', false, json::error_handler_t::replace));
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  const std::string text(reinterpret_cast<const char*>(data), size);
  try {
    json scene = fc::parseSceneText(text, sceneOrigin());
    {
      // What the server does with a scene file it loaded: GET
      // /api/scenes/{name} serialises it, a session keeps a copy.
      const json copy = scene;
      (void)copy.dump(-1, ' ', false, json::error_handler_t::replace);
    }
    // loadSceneJson's checks after parsing (run_command's path).
    if (!scene.is_object()) return 0;
    fc::resolveSceneFilePaths(scene, sceneOrigin());
    const int dimension = fc::sceneDimension(scene);
    FUZZ_CHECK(dimension == 2 || dimension == 3, "sceneDimension returned " + std::to_string(dimension));
    if (dimension == 2) validate<2>(scene);
    else validate<3>(scene);
    // `--scale NAME` (run, record, bench scenes): each named resolution of a valid scene.
    if (const auto scales = scene.find("scales"); scales != scene.end() && scales->is_object())
      for (const auto& item : scales->items()) {
        const json scaled = fc::applySceneScale(scene, item.key());
        if (dimension == 2) validate<2>(scaled);
        else validate<3>(scaled);
        // The folder its templates come from stays one name under the templates directory.
        const std::filesystem::path dir = fc::scaledTemplatesDir("templates", scene, item.key());
        FUZZ_CHECK(dir.parent_path() == "templates" && dir.filename() != ".." && dir.filename() != ".",
                   "a scale's templates folder left the templates directory: " + dir.string());
      }
  } catch (const fc::SceneError&) {
    // The documented error for a bad scene.
  }
  return 0;
}
