#pragma once
// A session's listeners (SessionListener, session.h): subscribed and called
// from any thread. A listener may unsubscribe itself or another one while it
// is being called (the lock is recursive); one that throws does not stop the others.
#include "service/session.h"

#include <cstdint>
#include <map>
#include <memory>
#include <mutex>
#include <vector>

namespace fc::service {

class SessionListeners {
 public:
  uint64_t subscribe(SessionListener listener) {
    std::lock_guard lk(mutex_);
    listeners_[++lastId_] = std::make_shared<SessionListener>(std::move(listener));
    return lastId_;
  }

  void unsubscribe(uint64_t id) {
    std::lock_guard lk(mutex_);
    listeners_.erase(id);
  }

  // Calls `call(listener, value)` on every listener, `value = make()` read
  // under the listeners' lock (so that the last call always carries the
  // newest value); nothing is made when no one listens.
  template <class Make, class Call>
  void notify(Make&& make, Call&& call) {
    std::lock_guard lk(mutex_);
    if (listeners_.empty()) return;
    const auto value = make();
    std::vector<std::shared_ptr<SessionListener>> ls;
    ls.reserve(listeners_.size());
    for (auto& [id, l] : listeners_) ls.push_back(l);
    for (const auto& l : ls) {
      // Unsubscribed by an earlier listener of this round: skip.
      bool still = false;
      for (auto& [id, m] : listeners_) still = still || m == l;
      if (!still) continue;
      try {
        call(*l, value);
      } catch (...) {
        // A listener's failure is its own; the session goes on.
      }
    }
  }

 private:
  std::recursive_mutex mutex_;
  std::map<uint64_t, std::shared_ptr<SessionListener>> listeners_;
  uint64_t lastId_ = 0;
};

}  // namespace fc::service
