#pragma once
// The optional layers (control, repulsion and boundary particles, moving
// bodies among them) of a recorded frame. The history keeps only the liquid,
// so the session's simulation goes back to the checkpoint before the frame
// and simulates up to it, which gives that frame bit for bit (checkpoints
// are exact), with the live state parked as an archive meanwhile and put
// back before the simulation next serves the live timeline. Scrubbing on
// continues from where the simulation is when that is nearer than a
// checkpoint.
#include "service/checkpoints.h"
#include "sph/simulation.h"
#include "sph/state_archive.h"

#include <functional>
#include <vector>

namespace fc::service {

template <int D>
class ReplayLayers {
 public:
  // Farther than this from a checkpoint (or from where the simulation is),
  // a recorded frame is shown without its layers: a scrub must stay cheap.
  static constexpr int kMaxFrames = 60;

  enum class Result { Ready, TooFar, Failed };

  bool parked() const { return parked_; }

  // The live state back into `sim` (no-op when not parked).
  void unpark(Simulation<D>& sim) {
    if (!parked_) return;
    StateArchive a(live_);
    sim.archiveState(a);
    parked_ = false;
    live_.clear();
    live_.shrink_to_fit();
    at_ = -1;
  }

  // Brings the session's simulation to the end of recorded frame `n`.
  // `sim` returns the session's simulation (`rebuild` replaces it by a
  // fresh one at frame 0, for frames before the first checkpoint).
  Result goTo(int n, const CheckpointStore& store, const std::function<Simulation<D>&()>& sim,
              const std::function<void()>& rebuild, const typename Simulation<D>::FrameLimits& limits) {
    const int checkpoint = n > 0 ? store.newestFrameAtOrBefore(n - 1) : 0;
    const bool onward = parked_ && at_ <= n && at_ >= checkpoint;
    const int from = onward ? at_ : checkpoint;
    if (n - from > kMaxFrames) return Result::TooFar;
    if (!parked_) {
      StateArchive a;
      sim().archiveState(a);
      live_ = std::move(a.bytes());
      parked_ = true;
    }
    if (!onward) {
      if (checkpoint > 0) {
        std::vector<uint8_t> archive;
        store.newestAtOrBefore(n - 1, archive);
        StateArchive a(archive);
        sim().archiveState(a);
      } else {
        rebuild();
      }
      at_ = checkpoint;
    }
    while (at_ < n) {
      sim().setFrameLimits(limits);
      const FrameStats fs = sim().advanceFrame();
      if (!fs.finite || fs.cancelled) {
        at_ = -2;  // somewhere in between: the next request restarts from a checkpoint
        return Result::Failed;
      }
      at_ = fs.frame;
    }
    return Result::Ready;
  }

 private:
  bool parked_ = false;
  std::vector<uint8_t> live_;  // the live simulation's state while parked
  int at_ = -1;                // the simulation's frame while parked
};

}  // namespace fc::service
