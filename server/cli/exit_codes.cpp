#include "cli/exit_codes.h"
#include "export/surface_export.h"
#include "io/frames_file.h"
#include "io/recipe.h"
#include "io/scene.h"
#include "io/template_database.h"
#include "io/template_file.h"
#include <cstdio>
#include <stdexcept>

namespace fc::cli {

int reportError(const std::string& origin, ExitCode otherwise) {
  try {
    throw;
  } catch (const SceneError& e) {
    // File-level errors already name the file (and line, column).
    if (e.path.empty()) std::fprintf(stderr, "error: %s\n", e.what());
    else std::fprintf(stderr, "error: %s: %s\n", origin.c_str(), e.what());
    return BadInput;
  } catch (const DatabaseError& e) {
    std::fprintf(stderr, "error: %s\n", e.what());
    return BadInput;
  } catch (const TemplateError& e) {
    std::fprintf(stderr, "error: %s\n", e.what());
    return BadInput;
  } catch (const ExportSetupError& e) {
    std::fprintf(stderr, "error: %s\n", e.what());
    return BadInput;
  } catch (const FramesFileError& e) {
    std::fprintf(stderr, "error: %s\n", e.what());
    return BadInput;
  } catch (const RecordAborted& e) {
    std::fprintf(stderr, "%s\n", e.what());
    return Interrupted;
  } catch (const std::invalid_argument& e) {
    std::fprintf(stderr, "error: %s: %s\n", origin.c_str(), e.what());
    return BadInput;
  } catch (const std::exception& e) {
    std::fprintf(stderr, "error: %s\n", e.what());
    return otherwise;
  }
}

}  // namespace fc::cli
