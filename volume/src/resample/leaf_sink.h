#pragma once
/// @file
/// Internal to palp_volume_core: where the resampler's filled leaves go (a grid's tree in
/// palp_volume, packed file bytes in palp convert), and resampling into such a sink. Free of
/// OpenVDB's library: its headers' coordinates and masks only.

#include <openvdb/math/Coord.h>
#include <openvdb/util/NodeMasks.h>

#include <Eigen/Core>

#include "palp/volume/resample_options.h"
#include "palp/volume/slice_stack.h"

namespace palp::volume::detail {

struct LazySliceStack;

/// Receives the leaves (8^3 blocks) the resampler fills, from its worker threads.
/// @par Threading  values() and take() from any number of threads at once (each thread's own
///      leaf); start() before and groupDone() between them, from the calling thread.
class LeafSink {
  public:
    virtual ~LeafSink() = default;
    /// Once, before any leaf: the lattice (voxel (i, j, k) centred at @p lo + @p step .* (i, j,
    /// k), metres) and the background value every inactive voxel holds.
    virtual void start(const Eigen::Vector3d& step, const Eigen::Vector3d& lo,
                       float background) = 0;
    /// 512 values the calling thread may fill for its next leaf (their content undefined),
    /// valid until that thread's next values() or take().
    virtual float* values() = 0;
    /// The leaf at @p origin with value mask @p mask (not empty) and 512 @p values (from
    /// values(), or the caller's own), every inactive value the background.
    virtual void take(const openvdb::Coord& origin, const openvdb::util::NodeMask<3>& mask,
                      float* values) = 0;
    /// After each group of leaves (no take() running).
    virtual void groupDone() {}
};

/// The resampler's test paths (FillContext).
struct FillPaths {
    bool referenceOnly = false;
    bool scalarRows = false;
    bool perBlockRows = false;
};

/// resample() of @p stack into @p sink: the same leaves on the same lattice; returns the
/// volume's info (threshold, values below it, spacing, tilt). With @p lazy (whose stack is
/// @p stack) the values are decoded as the blocks reach them (resampleLazy()). Checks nothing
/// of @p options (the caller runs checkResampleOptions()).
/// @throw what resample() and resampleLazy() throw.
VolumeInfo resampleInto(const SliceStack& stack, const ResampleOptions& options, LeafSink& sink,
                        const FillPaths& paths = {}, LazySliceStack* lazy = nullptr);

}  // namespace palp::volume::detail
