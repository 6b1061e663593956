#pragma once
// Binding a scene's instances to their templates (paper §3.5): what the
// instance model needs a loaded template for.
#include "control/instance.h"
#include "io/scene.h"
#include "sph/simulation.h"
#include "io/template_database.h"

#include <vector>

namespace fc {

// Loads every instance's template from the database, each template once:
// instances of one template share one TemplateAccel (an aliasing shared_ptr
// into the database's LoadedTemplate, which it keeps alive). Checks what needs
// the template (its existence, dimension and readability, the time map
// against its duration) and fills an empty transform track with one key
// {time 0, translation = the template region's centre}, i.e. the instance
// plays where the template was recorded.
//
// Throws SceneError with the path of the offending instance key:
//   instances[i].template    unknown template (the message names the database
//                            directory and lists its templates), a template of
//                            the other dimension, an unreadable file (with the
//                            TemplateError text), an invalid name;
//   instances[i].crop_begin / .crop_end / .speed / .start
//                            the time map does not fit the template's
//                            duration (TimeMap::validate);
//   instances[i].transform[k].<field>
//                            an invalid transform track (specs built outside
//                            parseSceneControl).
template <int D>
std::vector<BoundInstance<D>> bindInstances(const std::vector<InstanceSpec<D>>& specs, TemplateDatabase& database);

// Binds the scene's instances and appends the control stage to the
// simulation. A scene without instances gets no stage at all (nothing is
// loaded, nothing runs). Returns the number of instances. Throws as
// bindInstances.
template <int D>
size_t attachControl(Simulation<D>& sim, const SceneControl<D>& control, TemplateDatabase& database);

}  // namespace fc
