#include "io/instance_binding.h"
#include "control/control.h"

#include "io/template_file.h"

#include <map>
#include <string>

namespace fc {

namespace {

std::string instancePath(size_t i) { return "instances[" + std::to_string(i) + "]"; }

// "field: what" (TimeMap::validate, TransformTrack::validate after its "[k].")
// into a SceneError at base + separator + field.
[[noreturn]] void failWithField(const std::string& base, const std::string& separator, const std::string& err) {
  const size_t sep = err.find(": ");
  if (sep == std::string::npos) throw SceneError(base, err);
  throw SceneError(base + separator + err.substr(0, sep), err.substr(sep + 2));
}

std::string availableTemplates(const TemplateDatabase& db) {
  std::string out;
  for (const TemplateEntry& e : db.list()) {
    out += out.empty() ? "" : ", ";
    out += e.name;
    if (e.error.empty()) out += " (" + std::to_string(e.dimension) + "D)";
    else out += " (unreadable)";
  }
  return out.empty() ? "(none)" : out;
}

template <int D>
std::shared_ptr<const LoadedTemplate<D>> loadTemplate(const std::string& name, const std::string& path,
                                                      TemplateDatabase& db) {
  try {
    checkTemplateName(name);
    if (!db.contains(name))
      throw SceneError(path, "no template '" + name + "' in the template directory '" + db.directory() +
                                 "'; available: " + availableTemplates(db));
    // The header first, so that a template of the other dimension gets a plain message.
    const TemplateHeader h = readTemplateHeader(db.pathFor(name));
    if (h.dimension != D)
      throw SceneError(path, "template '" + name + "' is " + std::to_string(h.dimension) + "D but the scene is " +
                                 std::to_string(D) + "D");
    return db.load<D>(name);
  } catch (const DatabaseError& e) {
    throw SceneError(path, e.what());
  } catch (const TemplateError& e) {
    throw SceneError(path, std::string("cannot read template '") + name + "': " + e.what());
  }
}

}  // namespace

template <int D>
std::vector<BoundInstance<D>> bindInstances(const std::vector<InstanceSpec<D>>& specs, TemplateDatabase& db) {
  std::map<std::string, std::shared_ptr<const LoadedTemplate<D>>> loaded;
  std::vector<BoundInstance<D>> out;
  out.reserve(specs.size());
  for (size_t i = 0; i < specs.size(); ++i) {
    const std::string p = instancePath(i);
    const InstanceSpec<D>& spec = specs[i];
    if (const std::string err = spec.transform.validate(); !err.empty()) failWithField(p + ".transform", "", err);

    auto it = loaded.find(spec.templateName);
    if (it == loaded.end())
      it = loaded.emplace(spec.templateName, loadTemplate<D>(spec.templateName, p + ".template", db)).first;
    const std::shared_ptr<const LoadedTemplate<D>>& lt = it->second;

    BoundInstance<D> b;
    b.spec = spec;
    b.accel = std::shared_ptr<const TemplateAccel<D>>(lt, &lt->accel);
    if (const std::string err = spec.time.validate(b.templ().duration()); !err.empty()) failWithField(p, ".", err);
    if (b.spec.transform.keys.empty()) {
      TransformKey<D> key;
      key.time = 0;
      key.translation = b.centre().template cast<double>();
      b.spec.transform.keys.push_back(key);
    }
    out.push_back(std::move(b));
  }
  return out;
}

template <int D>
size_t attachControl(Simulation<D>& sim, const SceneControl<D>& control, TemplateDatabase& database) {
  if (control.instances.empty()) return 0;
  auto bound = bindInstances<D>(control.instances, database);
  const size_t n = bound.size();
  sim.addEffect(std::make_unique<Control<D>>(std::move(bound), control.settings), "control");
  return n;
}

template size_t attachControl<2>(Simulation<2>&, const SceneControl<2>&, TemplateDatabase&);
template size_t attachControl<3>(Simulation<3>&, const SceneControl<3>&, TemplateDatabase&);
template std::vector<BoundInstance<2>> bindInstances<2>(const std::vector<InstanceSpec<2>>&, TemplateDatabase&);
template std::vector<BoundInstance<3>> bindInstances<3>(const std::vector<InstanceSpec<3>>&, TemplateDatabase&);

}  // namespace fc
