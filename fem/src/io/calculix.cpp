#include "palp/fem/calculix.h"

#include <charconv>
#include <cmath>
#include <fstream>
#include <map>
#include <sstream>
#include <string>
#include <system_error>

#include "palp/base/atomic_file.h"
#include "palp/base/bounds.h"
#include "palp/base/error.h"
#include "palp/base/validate.h"

namespace palp::fem {

namespace {
// CalculiX C3D8 node order: bottom face counter-clockwise, then the top face.
constexpr int kCcxOrder[8] = {0, 1, 3, 2, 4, 5, 7, 6};
// Increments a dynamic step may ask ccx for (INC=): bounded so the count is an honest long.
constexpr double kMaxIncrements = 1e7;

/// The to_chars text [b, e) with its exponent compacted: no '+', no leading zeros
/// (`6.25e-05` -> `6.25e-5`, `1e+06` -> `1e6`).
std::string compactExponent(const char* b, const char* e) {
    std::string s(b, e);
    const std::size_t x = s.find('e');
    if (x == std::string::npos) return s;
    std::string out = s.substr(0, x + 1);
    std::size_t i = x + 1;
    if (s[i] == '+' || s[i] == '-') {
        if (s[i] == '-') out += '-';
        ++i;
    }
    while (i + 1 < s.size() && s[i] == '0') ++i;
    out.append(s, i, std::string::npos);
    return out;
}

std::string dofName(int d) {
    return "dof " + std::to_string(d) + " (node " + std::to_string(d / 3) + ", " + "xyz"[d % 3] +
           ")";
}

}  // namespace

std::string calculixNumber(double v) {
    if (!std::isfinite(v)) throwExpected("CalculiX number", "a finite value", formatValue(v));
    char buf[64];
    // Shortest round trip, fixed or scientific as printf would choose; then the shortest
    // scientific with its exponent compacted, which often beats it.
    auto r = std::to_chars(buf, buf + sizeof buf, v);
    std::string best = compactExponent(buf, r.ptr);
    r = std::to_chars(buf, buf + sizeof buf, v, std::chars_format::scientific);
    std::string sci = compactExponent(buf, r.ptr);
    if (sci.size() < best.size()) best = std::move(sci);
    // Too wide: the most significant digits that fit (precision = digits after the point).
    for (int p = 15; best.size() > kCalculixNumberWidth && p >= 0; --p) {
        r = std::to_chars(buf, buf + sizeof buf, v, std::chars_format::scientific, p);
        best = compactExponent(buf, r.ptr);
    }
    return best;
}

void writeCalculixInput(const std::filesystem::path& inpPath, const FemModel& model,
                        const Constraints& constraints, const Eigen::VectorXd& nodalForce,
                        const CalculixStep& step) {
    const HexMesh& mesh = model.mesh();
    if (constraints.dofCount() != model.dofCount() || nodalForce.size() != model.dofCount()) {
        std::ostringstream s;
        s << "CalculiX export: expected constraints and forces of " << model.dofCount()
          << " dofs, found " << constraints.dofCount() << " and " << nodalForce.size();
        throw ValueError(s.str());
    }
    // Everything is checked before the file is opened: a refusal leaves no file.
    for (int n = 0; n < mesh.nodeCount(); ++n) {
        if (mesh.nodeActive()[static_cast<std::size_t>(n)] && !mesh.nodePosition(n).allFinite()) {
            throwExpected("CalculiX export position of node " + std::to_string(n),
                          "finite coordinates in m", "a NaN or an infinity");
        }
    }
    for (int d = 0; d < model.dofCount(); ++d) {
        if (!std::isfinite(nodalForce[d])) {
            throwExpected("CalculiX export nodalForce " + dofName(d), "a finite force in N",
                          formatValue(nodalForce[d]));
        }
        if (constraints.isFixed(d) && !std::isfinite(constraints.values()[d])) {
            throwExpected("CalculiX export constraint value of " + dofName(d),
                          "a finite displacement in m", formatValue(constraints.values()[d]));
        }
    }
    if (step.dynamic) {
        requireWithin("CalculiX export step.timeIncrement", step.timeIncrement,
                      bounds::kPositiveDuration);
        requireWithin("CalculiX export step.totalTime", step.totalTime, bounds::kPositiveDuration);
        if (!(step.totalTime / step.timeIncrement <= kMaxIncrements)) {
            throwExpected("CalculiX export step.totalTime / step.timeIncrement",
                          "at most " + formatValue(kMaxIncrements) + " increments",
                          formatValue(step.totalTime / step.timeIncrement));
        }
        requireInRange("CalculiX export step.hhtAlpha", step.hhtAlpha, -1.0 / 3.0, 0.0);
    }
    if (step.elementType != "C3D8" && step.elementType != "C3D8R")
        throwExpected("CalculiX export step.elementType", "C3D8 or C3D8R",
                      "'" + step.elementType + "'");
    if (!(step.staticIncrement > 0.0 && step.staticIncrement <= 1.0)) {
        throwExpected("CalculiX export step.staticIncrement", "a fraction in (0, 1]",
                      formatValue(step.staticIncrement));
    }
    if (step.printEvery < 1) {
        throwExpected("CalculiX export step.printEvery", ">= 1", std::to_string(step.printEvery));
    }
    const auto num = calculixNumber;
    AtomicFile file(inpPath, "CalculiX input");
    std::ofstream out(file.tempPath());
    if (!out) throw IoError(inpPath.string() + ": expected a writable file, found none");
    out << "*HEADING\npalp hexahedral FEM export\n*NODE, NSET=Nall\n";
    for (int n = 0; n < mesh.nodeCount(); ++n) {
        if (!mesh.nodeActive()[static_cast<std::size_t>(n)]) continue;
        const Eigen::Vector3d p = mesh.nodePosition(n);
        out << n + 1 << ", " << num(p.x()) << ", " << num(p.y()) << ", " << num(p.z()) << "\n";
    }
    std::map<double, std::vector<int>> groups;
    for (int c = 0; c < mesh.cellCount(); ++c) {
        if (mesh.cellActive(c)) groups[mesh.cellYoungs()[static_cast<std::size_t>(c)]].push_back(c);
    }
    const ElasticMaterial& mat = model.material();
    const bool neoHookean = mat.law == MaterialLaw::neoHookean;
    int g = 0;
    for (const auto& [e, cells] : groups) {
        ++g;
        out << "*ELEMENT, TYPE=" << step.elementType << ", ELSET=E" << g << "\n";
        for (int c : cells) {
            const auto nodes = mesh.cellNodes(c);
            out << c + 1;
            for (int a : kCcxOrder) out << ", " << nodes[static_cast<std::size_t>(a)] + 1;
            out << "\n";
        }
        out << "*MATERIAL, NAME=M" << g << "\n";
        if (neoHookean) {
            // W = C10 (I1bar - 3) + (J - 1)^2 / D1 with the cell's small-strain mu and K.
            const double mu = e / (2.0 * (1.0 + mat.poissonRatio));
            const double bulk = e / (3.0 * (1.0 - 2.0 * mat.poissonRatio));
            out << "*HYPERELASTIC, NEO HOOKE\n" << num(0.5 * mu) << ", " << num(2.0 / bulk) << "\n";
        } else {
            out << "*ELASTIC\n" << num(e) << ", " << num(mat.poissonRatio) << "\n";
        }
        out << "*DENSITY\n" << num(mat.density) << "\n";
        if (mat.dampingAlpha > 0.0 || mat.dampingBeta > 0.0) {
            out << "*DAMPING, ALPHA=" << num(mat.dampingAlpha) << ", BETA=" << num(mat.dampingBeta)
                << "\n";
        }
        out << "*SOLID SECTION, ELSET=E" << g << ", MATERIAL=M" << g << "\n";
    }
    out << "*STEP";
    if (neoHookean) out << ", NLGEOM";
    if (!step.dynamic && step.staticIncrement < 1.0) out << ", INC=10000";
    if (step.dynamic)
        out << ", INC=" << static_cast<long>(step.totalTime / step.timeIncrement + 10);
    out << "\n";
    if (step.dynamic) {
        out << "*DYNAMIC, DIRECT, ALPHA=" << num(step.hhtAlpha) << "\n"
            << num(step.timeIncrement) << ", " << num(step.totalTime) << "\n";
    } else if (step.staticIncrement < 1.0) {
        out << "*STATIC\n" << num(step.staticIncrement) << ", 1\n";
    } else {
        out << "*STATIC\n";
    }
    out << "*BOUNDARY\n";
    for (int d = 0; d < model.dofCount(); ++d) {
        if (!constraints.isFixed(d) || !mesh.nodeActive()[static_cast<std::size_t>(d / 3)])
            continue;
        out << d / 3 + 1 << ", " << d % 3 + 1 << ", " << d % 3 + 1 << ", "
            << num(constraints.values()[d]) << "\n";
    }
    bool anyLoad = false;
    for (int d = 0; d < model.dofCount(); ++d) {
        if (nodalForce[d] == 0.0) continue;
        if (!anyLoad) out << "*CLOAD\n";
        anyLoad = true;
        out << d / 3 + 1 << ", " << d % 3 + 1 << ", " << num(nodalForce[d]) << "\n";
    }
    out << "*NODE PRINT, NSET=Nall, FREQUENCY=" << step.printEvery << "\nU"
        << (step.printReactions ? ", RF" : "") << "\n*END STEP\n";
    out.close();
    if (!out) throw IoError(inpPath.string() + ": expected a complete write, found an error");
    file.commit();
}

CalculixResults readCalculixDat(const std::filesystem::path& datPath, int dofCount) {
    std::ifstream in(datPath);
    if (!in)
        throw IoError(datPath.string() + ": expected a readable CalculiX .dat file, found none");
    CalculixResults res;
    std::string line;
    bool inBlock = false;
    Eigen::VectorXd* block = nullptr;
    while (std::getline(in, line)) {
        if (line.find("forces (fx,fy,fz)") != std::string::npos) {
            res.reactions.push_back(Eigen::VectorXd::Zero(dofCount));
            block = &res.reactions.back();
            inBlock = true;
            continue;
        }
        if (line.find("displacements (vx,vy,vz)") != std::string::npos) {
            const auto pos = line.find("time");
            if (pos == std::string::npos) {
                throw FormatError(datPath.string() +
                                  ": expected 'time' in a displacement header, "
                                  "found '" +
                                  line + "'");
            }
            res.times.push_back(std::stod(line.substr(pos + 4)));
            res.displacements.push_back(Eigen::VectorXd::Zero(dofCount));
            block = &res.displacements.back();
            inBlock = true;
            continue;
        }
        if (!inBlock) continue;
        std::istringstream s(line);
        long node = 0;
        double v[3];
        if (!(s >> node >> v[0] >> v[1] >> v[2])) {
            if (line.find_first_not_of(" \t\r") != std::string::npos) inBlock = false;
            continue;
        }
        if (node < 1 || 3 * node > dofCount) {
            std::ostringstream m;
            m << datPath.string() << ": expected node numbers in [1, " << dofCount / 3
              << "], found " << node;
            throw FormatError(m.str());
        }
        for (int c = 0; c < 3; ++c) (*block)[3 * (node - 1) + c] = v[c];
    }
    if (res.times.empty()) {
        throw FormatError(datPath.string() + ": expected displacement blocks, found none");
    }
    return res;
}

}  // namespace palp::fem
