#pragma once
// Export of a session's replay history for offline tools: the frames as one
// HDF5 file in the layout of `flowclip run --export` (io/frame_export.h,
// docs/export-format.md), plus an XDMF sidecar that ParaView (and VisIt)
// open as a time series of point clouds.
//
// The HDF5 file holds /frames/index, time, offset, count and
// /particles/position, velocity (float32, dequantized from the history's
// 16 bits), phase, kind. density, pressure and id are left out: the history
// does not hold them. Root attributes are the export's, plus
// source = "session replay history (16-bit quantized)".
//
// The XDMF file (XDMF 2, the format ParaView's "XDMF Reader" reads) is a
// temporal collection with one Polyvertex grid per frame holding particles
// (a frame without particles has no grid). Geometry (XY in 2D, XYZ in 3D) and
// the attributes velocity (vector), phase and kind (scalars) are HyperSlab
// selections of that frame's rows in the HDF5 datasets, referenced by the
// HDF5 file's name: the two files must stay side by side.
#include "io/frame_export.h"
#include "service/session.h"

#include <string>
#include <vector>

namespace fc::service {

inline constexpr const char* kHistorySource = "session replay history (16-bit quantized)";

// The sidecar of h5Path: its extension replaced by .xdmf (appended if none).
std::string xdmfPathFor(const std::string& h5Path);

// Writes `frames` (oldest first, all of header.dimension) to h5Path and its
// sidecar. header.source and header.solverColumns are set here. Both files
// are written under hidden temporary names next to their final ones and
// moved there together (io/staged_files.h), replacing existing files (or
// only one of them), only once both are complete; on any failure neither
// final name changes and no temporary file stays; after a crash at any
// instant, recoverPublishing(directory) leaves both old or both new. Throws
// std::invalid_argument (no frames, frames of another dimension) and
// std::runtime_error naming h5Path (I/O).
HistoryExport writeHistoryExport(const std::string& h5Path, const std::vector<FramePtr>& frames, ExportHeader header);

}  // namespace fc::service
