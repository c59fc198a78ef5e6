#include "palp/fem/calculix.h"

#include <fstream>
#include <iomanip>
#include <map>
#include <sstream>
#include <string>

#include "palp/base/error.h"

namespace palp::fem {

namespace {
// CalculiX C3D8 node order: bottom face counter-clockwise, then the top face.
constexpr int kCcxOrder[8] = {0, 1, 3, 2, 4, 5, 7, 6};
}  // namespace

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
    std::ofstream out(inpPath);
    if (!out) throw IoError(inpPath.string() + ": expected a writable file, found none");
    out << std::setprecision(17);
    out << "*HEADING\npalp hexahedral FEM export\n*NODE, NSET=Nall\n";
    for (int n = 0; n < mesh.nodeCount(); ++n) {
        if (!mesh.nodeActive()[static_cast<std::size_t>(n)]) continue;
        const Eigen::Vector3d p = mesh.nodePosition(n);
        out << n + 1 << ", " << p.x() << ", " << p.y() << ", " << p.z() << "\n";
    }
    std::map<double, std::vector<int>> groups;
    for (int c = 0; c < mesh.cellCount(); ++c) {
        if (mesh.cellActive(c)) groups[mesh.cellYoungs()[static_cast<std::size_t>(c)]].push_back(c);
    }
    const ElasticMaterial& mat = model.material();
    int g = 0;
    for (const auto& [e, cells] : groups) {
        ++g;
        out << "*ELEMENT, TYPE=C3D8, ELSET=E" << g << "\n";
        for (int c : cells) {
            const auto nodes = mesh.cellNodes(c);
            out << c + 1;
            for (int a : kCcxOrder) out << ", " << nodes[static_cast<std::size_t>(a)] + 1;
            out << "\n";
        }
        out << "*MATERIAL, NAME=M" << g << "\n*ELASTIC\n"
            << e << ", " << mat.poissonRatio << "\n*DENSITY\n"
            << mat.density << "\n";
        if (mat.dampingAlpha > 0.0 || mat.dampingBeta > 0.0) {
            out << "*DAMPING, ALPHA=" << mat.dampingAlpha << ", BETA=" << mat.dampingBeta << "\n";
        }
        out << "*SOLID SECTION, ELSET=E" << g << ", MATERIAL=M" << g << "\n";
    }
    out << "*STEP";
    if (step.dynamic)
        out << ", INC=" << static_cast<long>(step.totalTime / step.timeIncrement + 10);
    out << "\n";
    if (step.dynamic) {
        out << "*DYNAMIC, DIRECT, ALPHA=" << step.hhtAlpha << "\n"
            << step.timeIncrement << ", " << step.totalTime << "\n";
    } else {
        out << "*STATIC\n";
    }
    out << "*BOUNDARY\n";
    for (int d = 0; d < model.dofCount(); ++d) {
        if (!constraints.isFixed(d) || !mesh.nodeActive()[static_cast<std::size_t>(d / 3)])
            continue;
        out << d / 3 + 1 << ", " << d % 3 + 1 << ", " << d % 3 + 1 << ", "
            << constraints.values()[d] << "\n";
    }
    bool anyLoad = false;
    for (int d = 0; d < model.dofCount(); ++d) {
        if (nodalForce[d] == 0.0) continue;
        if (!anyLoad) out << "*CLOAD\n";
        anyLoad = true;
        out << d / 3 + 1 << ", " << d % 3 + 1 << ", " << nodalForce[d] << "\n";
    }
    out << "*NODE PRINT, NSET=Nall, FREQUENCY=" << step.printEvery << "\nU\n*END STEP\n";
    if (!out) throw IoError(inpPath.string() + ": expected a complete write, found an error");
}

CalculixResults readCalculixDat(const std::filesystem::path& datPath, int dofCount) {
    std::ifstream in(datPath);
    if (!in)
        throw IoError(datPath.string() + ": expected a readable CalculiX .dat file, found none");
    CalculixResults res;
    std::string line;
    bool inBlock = false;
    while (std::getline(in, line)) {
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
        for (int c = 0; c < 3; ++c) res.displacements.back()[3 * (node - 1) + c] = v[c];
    }
    if (res.times.empty()) {
        throw FormatError(datPath.string() + ": expected displacement blocks, found none");
    }
    return res;
}

}  // namespace palp::fem
