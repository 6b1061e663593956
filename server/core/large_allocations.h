#pragma once
// Large buffers served from the heap and kept for reuse. glibc maps every
// allocation above 32 MB afresh and unmaps it when freed, so the surface
// reconstruction's per-frame buffers (hundreds of MB at a million particles)
// had their pages faulted in and cleared by the kernel again every frame.
// For the commands that export surfaces frame after frame; the server keeps
// glibc's defaults, so that what a run frees goes back to the system.
namespace fc {

void reuseLargeAllocations();

}  // namespace fc
