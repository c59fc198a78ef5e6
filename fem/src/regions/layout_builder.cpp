#include "regions/layout_builder.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <queue>
#include <sstream>
#include <string>
#include <utility>

#include "index_cast.h"
#include "palp/base/error.h"
#include "regions/coarse_weights.h"

namespace palp::fem {

namespace {

using Triplet = Eigen::Triplet<double, int>;

}  // namespace

LayoutBuilder::LayoutBuilder(const AsyncSetup& setup, const std::vector<int>& contact)
    : mSetup(setup), mStiffness(setup.model.assembleStiffness()) {
    const AsyncRegionsOptions& o = setup.options;
    if (!o.globalSecondary || o.secondarySolver != LinearSolverKind::cholmod ||
        o.secondaryIntegrator != Integrator::quasiStatic)
        return;
    const std::vector<int> zone = zoneCoarseNodes(setup, contact, &mSlide);
    if (zone.empty() || 3 * static_cast<int>(zone.size()) > o.slideZoneMaxDofs) {
        mSlide.clear();
        return;
    }
    mGlobal = std::make_unique<GlobalSecondary>(setup, mStiffness, zone);
}

std::vector<int> LayoutBuilder::zoneCoarseNodes(const AsyncSetup& setup,
                                                const std::vector<int>& contact,
                                                std::vector<std::uint8_t>* slideMark) {
    // The coarse nodes a primary around any slide node can reach: seeds lie within the graph
    // radius g of the largest seed count around the first contact (the same on a flat face),
    // primary cells touch a seed and are widened to coarse cells; J is their corners.
    const HexMesh& mesh = setup.model.mesh();
    const AsyncRegionsOptions& o = setup.options;
    const auto& nc = mesh.nodeCounts();
    std::vector<int> slide = o.slideNodes;
    if (slide.empty()) {
        for (int a = 0; a < 3 && slide.empty(); ++a) {
            for (int side : {0, nc[sz(a)] - 1}) {
                const bool all = std::all_of(contact.begin(), contact.end(), [&](int n) {
                    return mesh.nodeCoords(n)[sz(a)] == side;
                });
                if (!all) continue;
                for (int n = 0; n < mesh.nodeCount(); ++n)
                    if (mesh.nodeActive()[sz(n)] && mesh.nodeCoords(n)[sz(a)] == side)
                        slide.push_back(n);
                break;
            }
        }
    }
    if (slide.empty()) return {};
    if (slideMark != nullptr) {
        slideMark->assign(sz(mesh.nodeCount()), 0);
        for (int n : slide)
            if (n >= 0 && n < mesh.nodeCount()) (*slideMark)[sz(n)] = 1;
    }
    std::vector<int> distance;
    const int seeds = std::max(o.primaryNodes, o.maxPrimaryNodes);
    const std::vector<int> order = seedOrder(setup, contact, seeds, &distance);
    if (order.empty()) return {};
    const int g = distance[std::min(order.size(), sz(seeds)) - 1];
    const int lod = setup.lod;
    const std::array<int, 3>& cc = setup.coarseCounts;
    std::vector<std::uint8_t> mark(sz(cc[0] * cc[1] * cc[2]), 0);
    std::vector<int> out;
    for (int n : slide) {
        if (n < 0 || n >= mesh.nodeCount() || !mesh.nodeActive()[sz(n)]) continue;
        const auto ijk = mesh.nodeCoords(n);
        std::array<int, 3> lo{}, hi{};
        for (int a = 0; a < 3; ++a) {
            lo[sz(a)] = std::max(0, ijk[sz(a)] - g - 1) / lod;
            hi[sz(a)] = std::min(cc[sz(a)] - 1, (ijk[sz(a)] + g) / lod + 1);
        }
        for (int Z = lo[2]; Z <= hi[2]; ++Z)
            for (int Y = lo[1]; Y <= hi[1]; ++Y)
                for (int X = lo[0]; X <= hi[0]; ++X) {
                    const int cn = X + cc[0] * (Y + cc[1] * Z);
                    if (mark[sz(cn)]) continue;
                    mark[sz(cn)] = 1;
                    out.push_back(cn);
                }
    }
    return out;
}

std::unique_ptr<Layout> LayoutBuilder::build(const std::vector<int>& contact, int seedCount,
                                             bool capacitanceOnly) const {
    auto layout = std::make_unique<Layout>();
    Layout& L = *layout;
    L.seeds = seedCount;
    L.generation = mNextGeneration.fetch_add(1, std::memory_order_relaxed);
    L.contactNodes = contact;
    const std::vector<std::uint8_t> driven = drivenDofs(contact, L);
    const std::vector<std::uint8_t> primaryCell =
        primaryCells(seedOrder(mSetup, contact, seedCount), seedCount);
    const std::vector<std::uint8_t> touchesPrimary = classifyNodes(primaryCell, driven, contact, L);
    collectPrimaryDofs(primaryCell, touchesPrimary, driven, L);
    if (mGlobal && buildGlobal(primaryCell, L)) {
        checkPrescribed(L);
        return layout;
    }
    if (capacitanceOnly) return nullptr;
    const SparseMatrix interp = interpolation(primaryCell, driven, L);
    restrictInterpolation(L);
    assembleSecondary(interp, L);
    sizeWorkVectors(L);
    checkPrescribed(L);
    return layout;
}

std::vector<std::uint8_t> LayoutBuilder::drivenDofs(const std::vector<int>& contact,
                                                    Layout& L) const {
    // Displacement drive: the contact dofs are driven, fixed for this layout. Force drive: they
    // are free and only centre the regions.
    std::vector<std::uint8_t> driven = mSetup.fixed;
    for (int n : contact) {
        if (mSetup.forceDrive) break;
        for (int k = 0; k < 3; ++k) {
            L.contactDofs.push_back(3 * n + k);
            driven[sz(3 * n + k)] = 1;
        }
    }
    return driven;
}

bool LayoutBuilder::buildGlobal(const std::vector<std::uint8_t>& primaryCell, Layout& L) const {
    // The secondary from the whole body's factor: no assembly, no factorisation.
    const HexMesh& mesh = mSetup.model.mesh();
    const int lod = mSetup.lod;
    const std::array<int, 3>& cc = mSetup.coarseCounts;
    const auto cellCounts = mesh.cellCounts();
    std::vector<std::uint8_t> coarseMark(sz((cc[0] - 1) * (cc[1] - 1) * (cc[2] - 1)), 0);
    L.primaryCoarseCells.clear();
    for (int k = 0; k < cellCounts[2]; ++k)
        for (int j = 0; j < cellCounts[1]; ++j)
            for (int i = 0; i < cellCounts[0]; ++i) {
                if (!primaryCell[sz(mesh.cell(i, j, k))]) continue;
                const int cell = i / lod + (cc[0] - 1) * (j / lod + (cc[1] - 1) * (k / lod));
                if (coarseMark[sz(cell)]) continue;
                coarseMark[sz(cell)] = 1;
                L.primaryCoarseCells.push_back(cell);
            }
    L.global = mGlobal.get();
    L.unknownCoarseDof = mGlobal->unknownCoarseDof();
    L.interp = mGlobal->interpolation();
    restrictInterpolation(L);
    if (!mGlobal->prepareLayout(L, L.primaryCoarseCells, mStiffness)) {
        // J leaves the zone: back to the layout's own assembly and factorisation.
        L.global = nullptr;
        L.unknownCoarseDof.clear();
        L.borderDofs.clear();
        L.capJ.clear();
        L.gammaResponse.resize(0, 0);
        L.watchResponse.resize(0, 0);
        L.watchInZone = false;
        L.response.resize(0, 0);
        L.gammaBasis.clear();
        return false;
    }
    sizeWorkVectors(L);
    L.loadZone = Eigen::VectorXd::Zero(mGlobal->zoneSize());
    L.zoneWork = L.loadZone;
    L.loadRhs = L.x;
    return true;
}

std::vector<int> LayoutBuilder::seedOrder(const AsyncSetup& setup, const std::vector<int>& contact,
                                          int count, std::vector<int>* distance) {
    return primarySeedOrder(setup.model.mesh(), contact, count, distance);
}

std::vector<int> primarySeedOrder(const HexMesh& mesh, const std::vector<int>& contact, int count,
                                  std::vector<int>* distance) {
    // Graph distance over lattice edges between active nodes (BFS from all contact nodes), ties
    // broken by Euclidean distance. The BFS discovers nodes in graph-distance order, so once
    // count nodes are found (the last at distance D), every node of distance below D is found
    // and those of distance D are found by expanding the nodes below D only: the first count
    // of the whole body's order lie among the nodes found (each layout build searched and
    // sorted all 35,301 nodes of the bone phantom's 2.5 mm body before).
    const auto& nc = mesh.nodeCounts();
    const int nodes = mesh.nodeCount();
    const auto& active = mesh.nodeActive();
    std::vector<int> dist(sz(nodes), -1);
    std::vector<int> found;
    std::queue<int> frontier;
    for (int n : contact) {
        if (dist[sz(n)] < 0) {
            dist[sz(n)] = 0;
            frontier.push(n);
            found.push_back(n);
        }
    }
    const std::size_t want = sz(std::max(count, 0));
    int stopAt = std::numeric_limits<int>::max();  // D, once count nodes are found
    while (!frontier.empty()) {
        const int n = frontier.front();
        if (found.size() >= want && stopAt == std::numeric_limits<int>::max())
            stopAt = want > 0 ? dist[sz(found[want - 1])] : 0;
        if (dist[sz(n)] >= stopAt) break;
        frontier.pop();
        const auto ijk = mesh.nodeCoords(n);
        for (int a = 0; a < 3; ++a) {
            for (int s = -1; s <= 1; s += 2) {
                std::array<int, 3> q = ijk;
                q[sz(a)] += s;
                if (q[sz(a)] < 0 || q[sz(a)] >= nc[sz(a)]) continue;
                const int m = mesh.node(q[0], q[1], q[2]);
                if (!active[sz(m)] || dist[sz(m)] >= 0) continue;
                dist[sz(m)] = dist[sz(n)] + 1;
                frontier.push(m);
                found.push_back(m);
            }
        }
    }
    std::vector<std::pair<double, int>> order;
    order.reserve(found.size());
    for (int n : found) {
        double e = std::numeric_limits<double>::infinity();
        for (int cn : contact)
            e = std::min(e, (mesh.nodePosition(n) - mesh.nodePosition(cn)).norm());
        order.emplace_back(dist[sz(n)] * 1e6 + e / mesh.edge(), n);
    }
    const std::size_t keep = std::min(order.size(), want);
    std::partial_sort(order.begin(), order.begin() + static_cast<std::ptrdiff_t>(keep),
                      order.end());
    order.resize(keep);
    std::vector<int> sorted(order.size());
    for (std::size_t i = 0; i < order.size(); ++i) sorted[i] = order[i].second;
    if (distance != nullptr) {
        distance->resize(order.size());
        for (std::size_t i = 0; i < order.size(); ++i) (*distance)[i] = dist[sz(sorted[i])];
    }
    return sorted;
}

std::vector<std::uint8_t> LayoutBuilder::primaryCells(const std::vector<int>& order,
                                                      int seedCount) const {
    return primaryCellsOf(mSetup.model.mesh(), order, seedCount, mSetup.lod);
}

std::vector<std::uint8_t> primaryCellsOf(const HexMesh& mesh, const std::vector<int>& order,
                                         int seedCount, int lod) {
    // Cells touching a seed, widened to whole coarse cells.
    const std::size_t seeds = std::min(order.size(), sz(seedCount));
    const std::array<int, 3> cc = mesh.cellCounts();
    std::vector<std::uint8_t> primaryCell(sz(mesh.cellCount()), 0);
    for (std::size_t s = 0; s < seeds; ++s) {
        const auto ijk = mesh.nodeCoords(order[s]);
        for (int dk = -1; dk <= 0; ++dk) {
            for (int dj = -1; dj <= 0; ++dj) {
                for (int di = -1; di <= 0; ++di) {
                    const int ci = ijk[0] + di, cj = ijk[1] + dj, ck = ijk[2] + dk;
                    if (ci < 0 || cj < 0 || ck < 0 || ci >= cc[0] || cj >= cc[1] || ck >= cc[2])
                        continue;
                    if (!mesh.cellActive(mesh.cell(ci, cj, ck))) continue;
                    const int bi = ci / lod * lod, bj = cj / lod * lod, bk = ck / lod * lod;
                    for (int k = bk; k < std::min(bk + lod, cc[2]); ++k) {
                        for (int j = bj; j < std::min(bj + lod, cc[1]); ++j) {
                            for (int i = bi; i < std::min(bi + lod, cc[0]); ++i) {
                                primaryCell[sz(mesh.cell(i, j, k))] = 1;
                            }
                        }
                    }
                }
            }
        }
    }
    return primaryCell;
}

std::vector<std::uint8_t> primaryRegionCells(const HexMesh& mesh,
                                             const std::vector<int>& contactNodes, int seeds,
                                             int lod) {
    for (int n : contactNodes)
        if (n < 0 || n >= mesh.nodeCount() || !mesh.nodeActive()[sz(n)])
            throw ValueError("primaryRegionCells: contact node " + std::to_string(n) +
                             " is not an active node of the mesh");
    if (lod < 1)
        throw ValueError("primaryRegionCells: lod: expected >= 1, found " + std::to_string(lod));
    return primaryCellsOf(mesh, primarySeedOrder(mesh, contactNodes, seeds), seeds, lod);
}

std::vector<std::uint8_t> LayoutBuilder::classifyNodes(const std::vector<std::uint8_t>& primaryCell,
                                                       const std::vector<std::uint8_t>& driven,
                                                       const std::vector<int>& contact,
                                                       Layout& L) const {
    // P: active nodes all of whose active cells are primary.
    const HexMesh& mesh = mSetup.model.mesh();
    const int nodes = mesh.nodeCount();
    std::vector<std::uint8_t> touchesPrimary(sz(nodes), 0), touchesSecondary(sz(nodes), 0);
    for (int c = 0; c < mesh.cellCount(); ++c) {
        if (!mesh.cellActive(c)) continue;
        for (int n : mesh.cellNodes(c)) {
            (primaryCell[sz(c)] ? touchesPrimary : touchesSecondary)[sz(n)] = 1;
        }
    }
    L.isPrimary.assign(sz(nodes), 0);
    for (int n = 0; n < nodes; ++n) {
        if (touchesPrimary[sz(n)] && !touchesSecondary[sz(n)]) {
            L.isPrimary[sz(n)] = 1;
            L.primaryNodes.push_back(n);
            bool allFixed = true;
            for (int k = 0; k < 3; ++k) allFixed = allFixed && driven[sz(3 * n + k)];
            if (!allFixed || std::find(contact.begin(), contact.end(), n) != contact.end())
                ++L.freeNodeCount;
        }
    }
    return touchesPrimary;
}

void LayoutBuilder::collectPrimaryDofs(const std::vector<std::uint8_t>& primaryCell,
                                       const std::vector<std::uint8_t>& touchesPrimary,
                                       const std::vector<std::uint8_t>& driven, Layout& L) const {
    // The primary operator's cells, the dofs it touches and integrates, and Gamma.
    const HexMesh& mesh = mSetup.model.mesh();
    const int nodes = mesh.nodeCount();
    const Eigen::VectorXd& mass = mSetup.model.lumpedMass();
    std::vector<int> cellIndex(sz(mesh.cellCount()), -1);
    for (int c = 0; c < mesh.cellCount(); ++c) {
        if (!mesh.cellActive(c) || !primaryCell[sz(c)]) continue;
        std::array<int, 8> d{};
        const auto cn = mesh.cellNodes(c);
        for (int a = 0; a < 8; ++a) d[sz(a)] = 3 * cn[sz(a)];
        cellIndex[sz(c)] = static_cast<int>(L.cellDofs.size());
        L.cellDofs.push_back(d);
        L.cellE.push_back(mesh.cellYoungs()[sz(c)]);
    }
    std::vector<std::uint8_t> seam;  // per primary cell (neo-Hookean model)
    if (mSetup.tled) {
        seam.assign(L.cellDofs.size(), 0);
        L.seamCellStart.push_back(0);
        for (std::size_t i = 0; i < L.cellDofs.size(); ++i) {
            bool inside = true;
            for (int d : L.cellDofs[i]) inside = inside && L.isPrimary[sz(d / 3)];
            if (inside) {
                L.tledCellDofs.push_back(L.cellDofs[i]);
                L.tledCellE.push_back(L.cellE[i]);
            } else {
                seam[i] = 1;
            }
        }
    }
    // P nodes by rows: the unit stencil where all eight cells are present with one modulus.
    const std::array<int, 3> cc = mesh.cellCounts();
    L.edgeCellStart.push_back(0);
    for (int n : L.primaryNodes) {
        const std::array<int, 3> x = mesh.nodeCoords(n);
        std::array<std::array<int, 2>, 8> cells{};
        int count = 0;
        bool uniform = true;
        for (int corner = 0; corner < 8; ++corner) {
            // The cell on the low (bit 0) or high side of the node per axis; the node is its
            // opposite corner there.
            std::array<int, 3> at{};
            bool inside = true;
            for (std::size_t k = 0; k < 3; ++k) {
                at[k] = x[k] - 1 + ((corner >> k) & 1);
                inside = inside && at[k] >= 0 && at[k] < cc[k];
            }
            if (!inside) continue;
            const int c = mesh.cell(at[0], at[1], at[2]);
            if (!mesh.cellActive(c) || cellIndex[sz(c)] < 0) continue;
            const int index = cellIndex[sz(c)];
            cells[sz(count++)] = {index, 7 - corner};
            uniform = uniform && L.cellE[sz(index)] == L.cellE[sz(cells[0][0])];
        }
        if (mSetup.tled) {
            bool any = false;
            for (int i = 0; i < count; ++i) {
                if (!seam[sz(cells[sz(i)][0])]) continue;
                L.seamCells.push_back(cells[sz(i)]);
                any = true;
            }
            if (any) {
                L.seamNodes.push_back(n);
                L.seamCellStart.push_back(static_cast<int>(L.seamCells.size()));
            }
        }
        if (count == 8 && uniform) {
            L.stencilNodes.push_back(n);
            L.stencilE.push_back(L.cellE[sz(cells[0][0])]);
        } else {
            L.edgeNodes.push_back(n);
            for (int i = 0; i < count; ++i) L.edgeCells.push_back(cells[sz(i)]);
            L.edgeCellStart.push_back(static_cast<int>(L.edgeCells.size()));
        }
    }
    for (int n = 0; n < nodes; ++n) {
        if (!touchesPrimary[sz(n)]) continue;
        for (int k = 0; k < 3; ++k) {
            const int d = 3 * n + k;
            L.touchedDofs.push_back(d);
            const bool free = !driven[sz(d)] && mass[d] > 0.0;
            if (L.isPrimary[sz(n)]) {
                if (free) L.freeDofs.push_back(d);
            } else if (free) {
                L.gammaDofs.push_back(d);
            }
        }
        if (!L.isPrimary[sz(n)]) L.gammaNodes.push_back(n);
    }
    L.isGamma.assign(sz(nodes), 0);
    for (int n : L.gammaNodes) L.isGamma[sz(n)] = 1;
}

SparseMatrix LayoutBuilder::interpolation(const std::vector<std::uint8_t>& primaryCell,
                                          const std::vector<std::uint8_t>& driven,
                                          Layout& L) const {
    // Interpolation from the coarse secondary: each free fine S dof takes trilinear weights of
    // the corners of a secondary coarse cell containing its node.
    const HexMesh& mesh = mSetup.model.mesh();
    const int nodes = mesh.nodeCount();
    const auto& active = mesh.nodeActive();
    const Eigen::VectorXd& mass = mSetup.model.lumpedMass();
    const int lod = mSetup.lod;
    const std::array<int, 3>& coarseCounts = mSetup.coarseCounts;
    const std::array<int, 3> ccc{coarseCounts[0] - 1, coarseCounts[1] - 1, coarseCounts[2] - 1};
    auto coarseCellSecondary = [&](int I, int J, int K) {
        bool anyActive = false;
        for (int k = K * lod; k < (K + 1) * lod; ++k) {
            for (int j = J * lod; j < (J + 1) * lod; ++j) {
                for (int i = I * lod; i < (I + 1) * lod; ++i) {
                    const int c = mesh.cell(i, j, k);
                    if (primaryCell[sz(c)]) return false;
                    anyActive = anyActive || mesh.cellActive(c);
                }
            }
        }
        return anyActive;
    };
    std::vector<int> unknownOf(sz(mSetup.coarseDofs), -1);
    std::vector<Triplet> trip;
    for (int n = 0; n < nodes; ++n) {
        if (!active[sz(n)] || L.isPrimary[sz(n)]) continue;
        const auto ijk = mesh.nodeCoords(n);
        // Candidate coarse cells along each axis.
        std::array<std::array<int, 2>, 3> cand{};
        std::array<int, 3> candCount{};
        for (int a = 0; a < 3; ++a) {
            const int q = ijk[sz(a)] / lod;
            int count = 0;
            if (q < ccc[sz(a)]) cand[sz(a)][sz(count++)] = q;
            if (ijk[sz(a)] % lod == 0 && q - 1 >= 0) cand[sz(a)][sz(count++)] = q - 1;
            candCount[sz(a)] = count;
        }
        int I = -1, J = -1, K = -1;
        for (int a = 0; a < candCount[0] && I < 0; ++a) {
            for (int b = 0; b < candCount[1] && I < 0; ++b) {
                for (int e = 0; e < candCount[2] && I < 0; ++e) {
                    if (coarseCellSecondary(cand[0][sz(a)], cand[1][sz(b)], cand[2][sz(e)])) {
                        I = cand[0][sz(a)];
                        J = cand[1][sz(b)];
                        K = cand[2][sz(e)];
                    }
                }
            }
        }
        if (I < 0) continue;  // no secondary cell (cannot happen on a box): held at rest
        std::array<double, 8> weight{};
        if (!coarseWeights(mesh, lod, ijk, I, J, K, weight)) continue;  // held at rest
        for (int k = 0; k < 3; ++k) {
            const int d = 3 * n + k;
            if (driven[sz(d)] || mass[d] <= 0.0) continue;
            for (int corner = 0; corner < 8; ++corner) {
                const double w = weight[sz(corner)];
                if (w == 0.0) continue;
                const int X = I + (corner & 1), Y = J + ((corner >> 1) & 1), Z = K + (corner >> 2);
                const int fineCorner = mesh.node(X * lod, Y * lod, Z * lod);
                const int fineDof = 3 * fineCorner + k;
                if (driven[sz(fineDof)] || L.isPrimary[sz(fineCorner)]) continue;
                const int coarseDof = 3 * (X + coarseCounts[0] * (Y + coarseCounts[1] * Z)) + k;
                int& idx = unknownOf[sz(coarseDof)];
                if (idx < 0) {
                    idx = static_cast<int>(L.unknownCoarseDof.size());
                    L.unknownCoarseDof.push_back(coarseDof);
                }
                trip.emplace_back(d, idx, w);
            }
        }
    }
    const int unknowns = static_cast<int>(L.unknownCoarseDof.size());
    SparseMatrix interp(mSetup.model.dofCount(), unknowns);
    interp.setFromTriplets(trip.begin(), trip.end());
    L.interp = interp;
    return interp;
}

void LayoutBuilder::restrictInterpolation(Layout& L) const {
    // The rows of the interpolation at Gamma and at the watched nodes.
    const int unknowns = static_cast<int>(L.unknownCoarseDof.size());
    std::vector<Triplet> g;
    for (std::size_t r = 0; r < L.gammaDofs.size(); ++r) {
        for (RowSparseMatrix::InnerIterator it(L.interp, L.gammaDofs[r]); it; ++it)
            g.emplace_back(static_cast<int>(r), static_cast<int>(it.col()), it.value());
    }
    L.interpGamma.resize(static_cast<int>(L.gammaDofs.size()), unknowns);
    L.interpGamma.setFromTriplets(g.begin(), g.end());
    std::vector<Triplet> w;
    const std::vector<int>& watch = mSetup.options.watchNodes;
    for (std::size_t i = 0; i < watch.size(); ++i) {
        for (int k = 0; k < 3; ++k) {
            for (RowSparseMatrix::InnerIterator it(L.interp, 3 * watch[i] + k); it; ++it)
                w.emplace_back(static_cast<int>(3 * i) + k, static_cast<int>(it.col()), it.value());
        }
    }
    L.interpWatch.resize(3 * static_cast<int>(watch.size()), unknowns);
    L.interpWatch.setFromTriplets(w.begin(), w.end());
}

void LayoutBuilder::assembleSecondary(const SparseMatrix& interp, Layout& L) const {
    // Galerkin system I^T K I, I^T M I and the coupling I^T K to the primary border.
    const int unknowns = static_cast<int>(L.unknownCoarseDof.size());
    const SparseMatrix interpT = interp.transpose();
    const SparseMatrix ik = interpT * mStiffness;  // unknowns x fine dofs
    L.kc = ik * interp;
    Eigen::VectorXd m = mSetup.model.lumpedMass();
    L.mc = interpT * m.asDiagonal() * interp;
    // Coupling to the P dofs: columns of I^T K at primary nodes that are not all zero.
    std::vector<Triplet> kb;
    for (int n : L.primaryNodes) {
        for (int k = 0; k < 3; ++k) {
            const int d = 3 * n + k;
            bool any = false;
            for (SparseMatrix::InnerIterator it(ik, d); it; ++it) {
                if (it.value() == 0.0) continue;
                if (!any) {
                    any = true;
                    L.borderDofs.push_back(d);
                }
                kb.emplace_back(static_cast<int>(it.row()),
                                static_cast<int>(L.borderDofs.size()) - 1, it.value());
            }
        }
    }
    L.kcb.resize(unknowns, static_cast<int>(L.borderDofs.size()));
    L.kcb.setFromTriplets(kb.begin(), kb.end());
}

void LayoutBuilder::sizeWorkVectors(Layout& L) const {
    const Eigen::Index unknowns = static_cast<Eigen::Index>(L.unknownCoarseDof.size());
    L.x = Eigen::VectorXd::Zero(unknowns);
    L.v = L.x;
    L.a = L.x;
    L.rhs = L.x;
    L.xNew = L.x;
    L.yc = L.x;
    L.ym = L.x;
    L.pcg.r = L.x;
    L.pcg.z = L.x;
    L.pcg.p = L.x;
    L.pcg.q = L.x;
    L.border = Eigen::VectorXd::Zero(static_cast<Eigen::Index>(L.borderDofs.size()));
}

void LayoutBuilder::checkPrescribed(const Layout& L) const {
    // Non-zero prescribed values on secondary nodes are not supported (the secondary's
    // right-hand side has no term for them).
    const int nodes = mSetup.model.mesh().nodeCount();
    for (int n = 0; n < nodes; ++n) {
        if (mSetup.nonZeroPrescribed[sz(n)] && !L.isPrimary[sz(n)]) {
            throw ValueError(
                "async regions constraints: expected zero prescribed displacement on secondary "
                "nodes, found a non-zero value at node " +
                std::to_string(n));
        }
    }
}

std::unique_ptr<Layout> LayoutBuilder::buildPrepared(int node, int seeds,
                                                     bool capacitanceOnly) const {
    std::unique_ptr<Layout> next = build({node}, seeds, capacitanceOnly);
    if (next) prepare(*next);
    return next;
}

void LayoutBuilder::prepare(Layout& L) const {
    if (L.unknownCoarseDof.empty() || L.global != nullptr) return;
    const SparseMatrix a = mSetup.sK * L.kc + mSetup.sM * L.mc;
    factorise(a, L);
    takeResponses(a, L);
}

void LayoutBuilder::factorise(const SparseMatrix& a, Layout& L) const {
    if (mSetup.options.secondarySolver == LinearSolverKind::cholmod) {
        L.cholmod.compute(a);
        if (L.cholmod.info() != Eigen::Success) {
            std::ostringstream s;
            s << "async regions secondary: expected a positive definite system, found a failed "
                 "CHOLMOD factorisation ("
              << a.rows() << " unknowns; do the supports remove every rigid-body motion?)";
            throw ValueError(s.str());
        }
    } else {
        L.rowA = a;
        L.inverseDiagonal = a.diagonal().cwiseInverse();
    }
}

void LayoutBuilder::takeResponses(const SparseMatrix& a, Layout& L) const {
    // The secondary's response to the border: G for the condensed coupling (small entries
    // dropped), and the dense Gamma / watched responses of the direct quasi-static secondary.
    const AsyncRegionsOptions& o = mSetup.options;
    const bool direct = o.secondarySolver == LinearSolverKind::cholmod &&
                        o.secondaryIntegrator == Integrator::quasiStatic && !o.secondaryFullField;
    if (!(o.condensed || direct) || L.borderDofs.empty() || L.gammaDofs.empty()) return;
    Eigen::CholmodSupernodalLLT<SparseMatrix, Eigen::Lower> own;
    Eigen::CholmodSupernodalLLT<SparseMatrix, Eigen::Lower>* llt = &L.cholmod;
    if (o.secondarySolver != LinearSolverKind::cholmod) {
        own.compute(a);
        llt = &own;
    }
    const Eigen::MatrixXd rhs = -mSetup.sK * Eigen::MatrixXd(L.kcb);
    const Eigen::MatrixXd x = llt->solve(rhs);
    const Eigen::MatrixXd g = L.interpGamma * x;
    if (direct) {
        L.gammaResponse = g;
        if (L.interpWatch.rows() > 0) L.watchResponse = L.interpWatch * x;
    }
    if (!o.condensed) return;
    const double drop = o.condensedDropTolerance * g.cwiseAbs().maxCoeff();
    std::vector<Triplet> t;
    for (Eigen::Index c = 0; c < g.cols(); ++c) {
        for (Eigen::Index r = 0; r < g.rows(); ++r) {
            if (std::abs(g(r, c)) > drop)
                t.emplace_back(static_cast<int>(r), static_cast<int>(c), g(r, c));
        }
    }
    L.response.resize(static_cast<int>(g.rows()), static_cast<int>(g.cols()));
    L.response.setFromTriplets(t.begin(), t.end());
}

}  // namespace palp::fem
