#include "palp/fem/voxelize.h"

#include <openvdb/tools/Interpolation.h>
#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <cmath>
#include <limits>
#include <sstream>
#include <string>

#include "palp/base/bounds.h"
#include "palp/base/error.h"
#include "palp/base/parallel.h"
#include "palp/base/validate.h"

namespace palp::fem {

namespace {

/// Labels connected components of the cells with @p active set (cells sharing a node, i.e.
/// 26-neighbours); returns the label per cell (-1 for inactive) and the size per label.
std::vector<int> labelComponents(const std::array<int, 3>& cells,
                                 const std::vector<std::uint8_t>& active, std::vector<int>& sizes) {
    std::vector<int> label(active.size(), -1);
    std::vector<int> stack;
    const auto index = [&](int i, int j, int k) { return i + cells[0] * (j + cells[1] * k); };
    for (int seed = 0; seed < static_cast<int>(active.size()); ++seed) {
        if (!active[static_cast<std::size_t>(seed)] || label[static_cast<std::size_t>(seed)] >= 0) {
            continue;
        }
        const int id = static_cast<int>(sizes.size());
        sizes.push_back(0);
        stack.push_back(seed);
        label[static_cast<std::size_t>(seed)] = id;
        while (!stack.empty()) {
            const int c = stack.back();
            stack.pop_back();
            ++sizes.back();
            const int ci = c % cells[0], cj = (c / cells[0]) % cells[1],
                      ck = c / (cells[0] * cells[1]);
            for (int dk = -1; dk <= 1; ++dk) {
                for (int dj = -1; dj <= 1; ++dj) {
                    for (int di = -1; di <= 1; ++di) {
                        const int i = ci + di, j = cj + dj, k = ck + dk;
                        if (i < 0 || j < 0 || k < 0 || i >= cells[0] || j >= cells[1] ||
                            k >= cells[2]) {
                            continue;
                        }
                        const auto n = static_cast<std::size_t>(index(i, j, k));
                        if (active[n] && label[n] < 0) {
                            label[n] = id;
                            stack.push_back(static_cast<int>(n));
                        }
                    }
                }
            }
        }
    }
    return label;
}

/// InsideBone::drop on the cell masks: clears the soft cells (tissue, not bone) with bone on both
/// sides along at least two of the three lattice axes, but not skin, then the bone cells that share
/// no node with a soft cell left; returns how many cells it cleared.
int dropInsideBone(const std::array<int, 3>& cells, std::vector<std::uint8_t>& tissue,
                   const std::vector<std::uint8_t>& bone) {
    const std::array<int, 3> stride{1, cells[0], cells[0] * cells[1]};
    // Bit a: the cell lies strictly between two bone cells of its line along axis a.
    std::vector<std::uint8_t> between(tissue.size(), 0);
    for (int a = 0; a < 3; ++a) {
        const int b = (a + 1) % 3, c = (a + 2) % 3;
        const auto bit = static_cast<std::uint8_t>(1 << a);
        for (int ic = 0; ic < cells[static_cast<std::size_t>(c)]; ++ic) {
            for (int ib = 0; ib < cells[static_cast<std::size_t>(b)]; ++ib) {
                const int base = ib * stride[static_cast<std::size_t>(b)] +
                                 ic * stride[static_cast<std::size_t>(c)];
                const int step = stride[static_cast<std::size_t>(a)];
                int first = -1, last = -1;
                for (int t = 0; t < cells[static_cast<std::size_t>(a)]; ++t) {
                    if (!bone[static_cast<std::size_t>(base + t * step)]) continue;
                    if (first < 0) first = t;
                    last = t;
                }
                for (int t = first + 1; first >= 0 && t < last; ++t)
                    between[static_cast<std::size_t>(base + t * step)] |= bit;
            }
        }
    }
    const auto axes = [&](std::size_t n) {
        return (between[n] & 1) + ((between[n] >> 1) & 1) + ((between[n] >> 2) & 1);
    };
    // Two axes of three: a scan that stops above the skull base or below the vertex leaves the
    // brain open along the scan axis, and a plate or slab (one axis) encloses nothing. Skin
    // stays: a soft cell with a face on the air outside (a void cell itself enclosed on fewer
    // than two axes), e.g. the nape between the skull base and the spine.
    std::vector<std::size_t> drop;
    for (int k = 0; k < cells[2]; ++k) {
        for (int j = 0; j < cells[1]; ++j) {
            for (int i = 0; i < cells[0]; ++i) {
                const std::array<int, 3> ijk{i, j, k};
                const auto n = static_cast<std::size_t>(i + stride[1] * j + stride[2] * k);
                if (!tissue[n] || bone[n] || axes(n) < 2) continue;
                bool skin = false;
                for (int a = 0; a < 3 && !skin; ++a) {
                    for (int d = -1; d <= 1 && !skin; d += 2) {
                        const int t = ijk[static_cast<std::size_t>(a)] + d;
                        if (t < 0 || t >= cells[static_cast<std::size_t>(a)]) continue;
                        const auto m = static_cast<std::size_t>(
                            static_cast<long>(n) + d * stride[static_cast<std::size_t>(a)]);
                        skin = !tissue[m] && axes(m) < 2;
                    }
                }
                if (!skin) drop.push_back(n);
            }
        }
    }
    for (std::size_t n : drop) tissue[n] = 0;
    int cleared = static_cast<int>(drop.size());
    // Bone cells stay where they share a node with soft tissue (the supports under it).
    const std::vector<std::uint8_t> kept = tissue;
    for (int k = 0; k < cells[2]; ++k) {
        for (int j = 0; j < cells[1]; ++j) {
            for (int i = 0; i < cells[0]; ++i) {
                const auto n = static_cast<std::size_t>(i + stride[1] * j + stride[2] * k);
                if (!kept[n] || !bone[n]) continue;
                bool touches = false;
                for (int dk = -1; dk <= 1 && !touches; ++dk) {
                    for (int dj = -1; dj <= 1 && !touches; ++dj) {
                        for (int di = -1; di <= 1 && !touches; ++di) {
                            const int x = i + di, y = j + dj, z = k + dk;
                            if (x < 0 || y < 0 || z < 0 || x >= cells[0] || y >= cells[1] ||
                                z >= cells[2]) {
                                continue;
                            }
                            const auto m =
                                static_cast<std::size_t>(x + stride[1] * y + stride[2] * z);
                            touches = kept[m] && !bone[m];
                        }
                    }
                }
                if (!touches) {
                    tissue[n] = 0;
                    ++cleared;
                }
            }
        }
    }
    return cleared;
}

}  // namespace

void validate(const VoxelizeOptions& o) {
    requireWithin("voxelize elementSize", o.elementSize, bounds::kSpacing);
    requireWithin("voxelize tissueThreshold", o.tissueThreshold, bounds::kVolumeValue);
    if (o.boneThreshold != std::numeric_limits<double>::infinity()) {
        requireWithin("voxelize boneThreshold", o.boneThreshold, bounds::kVolumeValue);
    }
    if (o.maxCells < 1) throwExpected("voxelize maxCells", ">= 1", std::to_string(o.maxCells));
}

VoxelizedMesh voxelizeVolume(const volume::Volume& volume, const VoxelizeOptions& options) {
    validate(options);
    const double h = options.elementSize;
    // Any active value (voxel or tile) at all: the first one of a serial iteration, not
    // activeVoxelCount()'s TBB reduction over the whole tree.
    if (!volume.grid || !volume.grid->cbeginValueOn()) {
        throw ValueError("voxelize volume: expected a grid with active voxels, found none");
    }
    // World box of the active voxels themselves (centres +- half a voxel).
    const openvdb::BBoxd centres = volume.worldBounds();
    const double halfVoxel = 0.5 * volume.voxelSize();
    const Eigen::Vector3d lo(centres.min().x() - halfVoxel, centres.min().y() - halfVoxel,
                             centres.min().z() - halfVoxel);
    const Eigen::Vector3d hi(centres.max().x() + halfVoxel, centres.max().y() + halfVoxel,
                             centres.max().z() + halfVoxel);
    std::array<int, 3> cells{};
    long cellTotal = 1;
    for (int a = 0; a < 3; ++a) {
        // 1e-9 absorbs round-off when the extent is a multiple of h.
        const double count = std::ceil((hi[a] - lo[a]) / h - 1e-9);
        if (!(count <= static_cast<double>(options.maxCells))) {
            cellTotal = options.maxCells + 1;
            break;
        }
        cells[static_cast<std::size_t>(a)] = std::max(1, static_cast<int>(count));
        cellTotal *= cells[static_cast<std::size_t>(a)];
    }
    if (cellTotal > options.maxCells) {
        std::ostringstream s;
        s << "voxelize lattice: expected at most " << options.maxCells << " cells, found more at "
          << "element size " << h << " m over a " << (hi - lo).transpose()
          << " m box; choose a larger element size";
        throw ValueError(s.str());
    }

    // Sample the scan at every cell centre (world coordinates): trilinear, or the nearest
    // voxel's value for a label volume (a blend of two labels is no label).
    const auto cellCount = static_cast<std::size_t>(cellTotal);
    std::vector<double> value(cellCount, 0.0);
    const openvdb::FloatGrid& grid = *volume.grid;
    const auto sampleAll = [&]<class Sampler>(Sampler) {
        palp::parallelFor(
            tbb::blocked_range<int>(0, cells[2]), [&](const tbb::blocked_range<int>& r) {
                openvdb::FloatGrid::ConstAccessor accessor = grid.getConstAccessor();
                const openvdb::tools::GridSampler<openvdb::FloatGrid::ConstAccessor, Sampler>
                    sampler(accessor, grid.transform());
                for (int k = r.begin(); k != r.end(); ++k) {
                    for (int j = 0; j < cells[1]; ++j) {
                        for (int i = 0; i < cells[0]; ++i) {
                            const openvdb::Vec3d p(lo.x() + (i + 0.5) * h, lo.y() + (j + 0.5) * h,
                                                   lo.z() + (k + 0.5) * h);
                            value[static_cast<std::size_t>(i + cells[0] * (j + cells[1] * k))] =
                                static_cast<double>(sampler.wsSample(p));
                        }
                    }
                }
            });
    };
    if (options.nearestValue) {
        sampleAll(openvdb::tools::PointSampler{});
    } else {
        sampleAll(openvdb::tools::BoxSampler{});
    }

    std::vector<std::uint8_t> tissue(cellCount, 0);
    for (std::size_t c = 0; c < cellCount; ++c)
        tissue[c] = static_cast<std::uint8_t>(value[c] > options.tissueThreshold);
    VoxelizedMesh out;
    if (options.insideBone == InsideBone::drop) {
        std::vector<std::uint8_t> boneCell(cellCount, 0);
        for (std::size_t c = 0; c < cellCount; ++c)
            boneCell[c] = static_cast<std::uint8_t>(tissue[c] && value[c] > options.boneThreshold);
        out.insideBoneCells = dropInsideBone(cells, tissue, boneCell);
    }
    if (options.keepLargestComponent) {
        std::vector<int> sizes;
        const std::vector<int> label = labelComponents(cells, tissue, sizes);
        if (sizes.size() > 1) {
            const int keep =
                static_cast<int>(std::max_element(sizes.begin(), sizes.end()) - sizes.begin());
            for (std::size_t c = 0; c < cellCount; ++c) {
                if (tissue[c] && label[c] != keep) {
                    tissue[c] = 0;
                    ++out.droppedCells;
                }
            }
        }
    }

    std::vector<double> youngs(cellCount, 0.0);
    std::vector<std::uint8_t> bone(cellCount, 0);
    bool anyTissue = false;
    for (std::size_t c = 0; c < cellCount; ++c) {
        if (!tissue[c]) continue;
        anyTissue = true;
        const double e = options.youngsFromValue ? options.youngsFromValue(value[c]) : 5.0e3;
        if (!(e > 0.0) || !std::isfinite(e)) {
            std::ostringstream s;
            s << "voxelize transfer function: expected a finite Young's modulus > 0 Pa, found " << e
              << " Pa for scan value " << value[c];
            throw ValueError(s.str());
        }
        youngs[c] = e;
        bone[c] = static_cast<std::uint8_t>(value[c] > options.boneThreshold);
    }
    if (!anyTissue) {
        std::ostringstream s;
        s << "voxelize tissue: expected cells with a value above " << options.tissueThreshold
          << ", found none at element size " << h << " m";
        throw ValueError(s.str());
    }

    out.mesh =
        HexMesh::fromCells({cells[0] + 1, cells[1] + 1, cells[2] + 1}, h, lo, std::move(youngs));
    std::vector<std::uint8_t> boneNode(static_cast<std::size_t>(out.mesh.nodeCount()), 0);
    for (int c = 0; c < static_cast<int>(cellCount); ++c) {
        if (!bone[static_cast<std::size_t>(c)]) continue;
        for (int n : out.mesh.cellNodes(c)) boneNode[static_cast<std::size_t>(n)] = 1;
    }
    for (int n = 0; n < out.mesh.nodeCount(); ++n) {
        if (boneNode[static_cast<std::size_t>(n)]) out.boneNodes.push_back(n);
    }
    return out;
}

}  // namespace palp::fem
