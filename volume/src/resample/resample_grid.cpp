// resample() of slices into a grid: the resampler's leaves (resampleInto, palp_volume_core)
// added to a FloatGrid's tree.
#include <tbb/enumerable_thread_specific.h>

#include <algorithm>
#include <memory>
#include <vector>

#include "lazy_stack.h"
#include "palp/base/error.h"
#include "palp/volume/resample.h"
#include "resample/leaf_sink.h"
#include "resample/resample_detail.h"
#include "vdb/vdb_errors.h"

namespace palp::volume {

namespace {

using namespace detail;
using LeafT = openvdb::FloatTree::LeafNodeType;

/// Index-to-world transform of a lattice: a uniform scale for equal steps (as before native
/// spacing existed), else a per-axis scale; then a translation to @p lo (metres). The packed
/// writer (vdb_packed.cpp) writes the same maps.
openvdb::math::Transform::Ptr worldFromIndex(const Eigen::Vector3d& step,
                                             const Eigen::Vector3d& lo) {
    if (step.x() == step.y() && step.y() == step.z()) {
        auto xform = openvdb::math::Transform::createLinearTransform(step.x());
        xform->postTranslate(openvdb::Vec3d(lo.x(), lo.y(), lo.z()));
        return xform;
    }
    return std::make_shared<openvdb::math::Transform>(
        std::make_shared<openvdb::math::ScaleTranslateMap>(openvdb::Vec3d(step.data()),
                                                           openvdb::Vec3d(lo.data())));
}

/// The leaves go into a grid's tree: each thread fills the buffer of a spare leaf of its own,
/// which becomes the tree's when it holds an active voxel (a group's leaves are added after the
/// group, from the calling thread).
class TreeSink final : public LeafSink {
  public:
    void start(const Eigen::Vector3d& step, const Eigen::Vector3d& lo, float background) override {
        mGrid = openvdb::FloatGrid::create(background);
        mGrid->setName(kScanGridName);
        mGrid->setTransform(worldFromIndex(step, lo));
    }
    float* values() override { return spare()->buffer().data(); }
    void take(const openvdb::Coord& origin, const openvdb::util::NodeMask<3>& mask,
              float* values) override {
        std::unique_ptr<LeafT>& leaf = spare();
        if (values != leaf->buffer().data())
            std::copy_n(values, LeafT::SIZE, leaf->buffer().data());
        leaf->setOrigin(origin);
        leaf->setValueMask(mask);
        mMade.local().push_back(std::move(leaf));
    }
    void groupDone() override {
        for (auto& list : mMade) {
            for (auto& leaf : list) mGrid->tree().addLeaf(leaf.release());  // the tree owns it
            list.clear();
        }
    }
    openvdb::FloatGrid::Ptr grid() const { return mGrid; }

  private:
    /// The thread's spare leaf (its buffer allocated, not filled), made on demand.
    std::unique_ptr<LeafT>& spare() {
        std::unique_ptr<LeafT>& leaf = mSpare.local();
        if (!leaf) {
            leaf = std::make_unique<LeafT>(openvdb::PartialCreate(), openvdb::Coord(),
                                           mGrid->background(), false);
            leaf->allocate();
        }
        return leaf;
    }

    openvdb::FloatGrid::Ptr mGrid;
    tbb::enumerable_thread_specific<std::unique_ptr<LeafT>> mSpare;
    tbb::enumerable_thread_specific<std::vector<std::unique_ptr<LeafT>>> mMade;
};

/// resample() of @p stack (lazily decoded with @p lazy) by @p paths, as a Volume.
Volume resampleToGrid(const SliceStack& stack, const ResampleOptions& options,
                      const FillPaths& paths, LazySliceStack* lazy = nullptr) {
    return detail::withVdbErrors<ValueError>("resample", "a grid OpenVDB can build", [&] {
        TreeSink sink;
        Volume out;
        out.info = resampleInto(stack, options, sink, paths, lazy);
        out.grid = sink.grid();
        writeInfo(out.info, *out.grid);
        return out;
    });
}

}  // namespace

Volume resample(const SliceStack& stack, const ResampleOptions& options) {
    checkResampleOptions(options);
    return resampleToGrid(stack, options, {});
}

namespace detail {

Volume resampleLazy(LazySliceStack& lazy, const ResampleOptions& options) {
    checkResampleOptions(options);
    checkLazyValues(lazy);
    return resampleToGrid(lazy.stack, options, {}, &lazy);
}

Volume resampleVoxelByVoxel(const SliceStack& stack, const ResampleOptions& options) {
    checkResampleOptions(options);
    return resampleToGrid(stack, options, {.referenceOnly = true});
}

Volume resampleScalarRows(const SliceStack& stack, const ResampleOptions& options) {
    checkResampleOptions(options);
    return resampleToGrid(stack, options, {.scalarRows = true});
}

Volume resamplePerBlockRows(const SliceStack& stack, const ResampleOptions& options) {
    checkResampleOptions(options);
    return resampleToGrid(stack, options, {.perBlockRows = true});
}

}  // namespace detail

}  // namespace palp::volume
