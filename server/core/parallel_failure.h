#pragma once
// An exception may not leave an OpenMP region (it would terminate the
// process): each thread keeps the first one with keep() in its catch block,
// and rethrow() throws it after the region.
#include <exception>

namespace fc {

class ParallelFailure {
 public:
  void keep() {
#pragma omp critical(fc_parallel_failure)
    if (!failure_) failure_ = std::current_exception();
  }
  void rethrow() const {
    if (failure_) std::rethrow_exception(failure_);
  }

 private:
  std::exception_ptr failure_;
};

}  // namespace fc
