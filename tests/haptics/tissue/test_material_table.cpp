// Materials from the scan by a table (material_table.h): the CT table palp ships, a CT phantom
// with fat, soft tissue and a lesion made into elements whose moduli are the table's (the
// lesion's stiffer by the table's ratio), a label volume looked up by its nearest voxel, and
// every kind of bad table refused naming its file, line and row.

#include <gtest/gtest.h>

#include <cstdint>
#include <fstream>
#include <string>
#include <vector>

#include "palp/base/error.h"
#include "palp/fem/voxelize.h"
#include "palp/haptics/tissue/deformable_setup.h"
#include "palp/haptics/tissue/material_table.h"
#include "palp/volume/from_memory.h"
#include "palp/volume/phantom.h"
#include "test_support.h"

namespace palp::haptics {
namespace {

const MaterialRow& rowNamed(const MaterialTable& t, const std::string& name) {
    for (const MaterialRow& r : t.rows()) {
        if (r.name == name) return r;
    }
    ADD_FAILURE() << "no row " << name;
    return t.rows().front();
}

TEST(MaterialTable, TheShippedCtTableHasFatSoftTissueAndALesionWithSources) {
    const MaterialTable& t = MaterialTable::builtInCt();
    EXPECT_EQ(t.kind(), MaterialTableKind::ranges);
    ASSERT_EQ(t.rows().size(), 3u);
    for (const MaterialRow& r : t.rows()) {
        EXPECT_NE(r.source.find("Samani"), std::string::npos) << r.name;
        EXPECT_GT(r.line, 1) << r.name;
    }
    EXPECT_EQ(t.find(-100)->name, "fat");         // the phantoms' fat
    EXPECT_EQ(t.find(40)->name, "soft_tissue");   // their soft tissue
    EXPECT_EQ(t.find(200)->name, "lesion");       // the tumour phantom's inclusion
    EXPECT_EQ(t.find(-30)->name, "soft_tissue");  // lo <= v < hi
    EXPECT_EQ(t.find(-250), nullptr);             // below the fat window: air
    EXPECT_EQ(t.find(500), nullptr);              // bone takes no row
    EXPECT_EQ(t.poissonRatio(), 0.45);
    EXPECT_EQ(t.density(), 1000);
    EXPECT_THROW(t.youngsAt(-250), ValueError);
    EXPECT_EQ(MaterialTable::named("ct")->rows().size(), 3u);
}

// The tumour phantom (2 mm of fat over soft tissue at 40 HU, an 8 mm inclusion at 200 HU) at
// 1 mm voxels, voxelised into 1 mm cells (their centres on the voxels' centres) by the CT
// table: each cell's modulus is its class's by the phantom's geometry (not by the table's own
// lookup), and the lesion's elements are stiffer than the soft tissue's by the table's ratio.
TEST(MaterialTable, APhantomsFatSoftTissueAndLesionGetTheTablesModuli) {
    volume::PhantomSpec spec;
    spec.params.scene = volume::PhantomScene::Tumour;
    spec.voxelSize = 1e-3;
    const volume::Volume vol = volume::makePhantomVolume(spec);
    const volume::PhantomSphere lesion = volume::Phantom(spec.params).inclusion();
    auto table = std::make_shared<const MaterialTable>(MaterialTable::builtInCt());
    fem::VoxelizeOptions vo;
    vo.elementSize = 1e-3;
    vo.tissueThreshold = -200;
    vo.boneThreshold = 500;
    fem::ElasticMaterial material;
    applyMaterialTable(table, vo, material);
    EXPECT_FALSE(vo.nearestValue);
    // A bone cell (its nodes all fixed) takes the softest row's modulus: it never shortens the
    // explicit step the tissue's rows allow.
    EXPECT_EQ(vo.youngsFromValue(1000), table->softestModulus());
    EXPECT_EQ(material.poissonRatio, 0.45);
    EXPECT_EQ(material.youngsModulus, table->softestModulus());
    const fem::VoxelizedMesh vm = fem::voxelizeVolume(vol, vo);
    const fem::HexMesh& mesh = vm.mesh;
    const double eFat = rowNamed(*table, "fat").youngsModulus;
    const double eSoft = rowNamed(*table, "soft_tissue").youngsModulus;
    const double eLesion = rowNamed(*table, "lesion").youngsModulus;
    int fat = 0, soft = 0, inLesion = 0, wrong = 0;
    std::vector<double> seen;
    for (int c = 0; c < mesh.cellCount(); ++c) {
        if (!mesh.cellActive(c)) continue;
        const double e = mesh.cellYoungs()[static_cast<std::size_t>(c)];
        const Eigen::Vector3d centre =
            mesh.nodePosition(mesh.cellNodes(c)[0]) + Eigen::Vector3d::Constant(0.5e-3);
        const double fromLesion = (centre - lesion.centre).norm();
        double expect = 0;
        if (fromLesion < lesion.radius - 1e-3) {
            expect = eLesion;
            ++inLesion;
        } else if (centre.y() < 1.7e-3) {  // the fat is 2 mm thick
            expect = eFat;
            ++fat;
        } else if (centre.y() > 2.3e-3 && fromLesion > lesion.radius + 1e-3) {
            expect = eSoft;
            ++soft;
        } else {
            continue;  // a cell on a boundary between classes
        }
        if (e != expect) ++wrong;
    }
    EXPECT_EQ(wrong, 0);
    EXPECT_GT(fat, 1000);  // two layers of cells over the block's 100 x 100 mm face
    EXPECT_GT(soft, 100000);
    EXPECT_GT(inLesion, 1000);  // (8 - 1 mm)^3 x 4/3 pi ~ 1,400 cells
    // The lesion is stiffer than the tissue around it by the table's ratio, 19.99 / 3.24 kPa.
    EXPECT_DOUBLE_EQ(eLesion / eSoft, 19990.0 / 3240.0);
}

// A segmentation (labels 0 air, 1 soft tissue, 2 fat, 3 lesion) on 1 mm voxels, voxelised in
// 2 mm cells whose centres fall between voxels: a label table samples the nearest voxel, so
// every cell is one of its labels; the trilinear blend of labels 1 and 3 would be a value no
// label has, and is refused naming it.
TEST(MaterialTable, ALabelVolumeIsLookedUpByItsNearestVoxel) {
    constexpr int n = 24;
    std::vector<std::uint8_t> labels(n * n * n, 1);
    for (int k = 0; k < n; ++k)
        for (int j = 0; j < n; ++j)
            for (int i = 0; i < n; ++i) {
                std::uint8_t& v = labels[static_cast<std::size_t>(i + n * (j + n * k))];
                if (j < 3) v = 2;  // fat on top
                if (i >= 8 && i < 16 && j >= 9 && j < 17 && k >= 8 && k < 16) v = 3;
            }
    volume::MemoryGrid g;
    g.data = labels.data();
    g.type = volume::ValueType::UInt8;
    g.dims = {n, n, n};
    g.indexToWorld = Eigen::Matrix4d::Identity();
    g.indexToWorld.topLeftCorner<3, 3>() *= 1e-3;
    const volume::Volume vol = volume::fromMemory(g);
    auto table = std::make_shared<const MaterialTable>(
        MaterialTable::parse("# a segmentation's labels\n"
                             "name,label,youngs_pa,poisson,density_kg_m3,source\n"
                             "soft,1,4000,0.45,1000,test\n"
                             "fat,2,3000,0.45,1000,test\n"
                             "lesion,3,24000,0.45,1000,test\n",
                             "labels.csv"));
    EXPECT_EQ(table->kind(), MaterialTableKind::labels);
    fem::VoxelizeOptions vo;
    vo.elementSize = 2e-3;
    vo.tissueThreshold = 0.5;  // label 0 is air
    fem::ElasticMaterial material;
    applyMaterialTable(table, vo, material);
    EXPECT_TRUE(vo.nearestValue);
    const fem::HexMesh mesh = fem::voxelizeVolume(vol, vo).mesh;
    int lesion = 0, other = 0;
    for (int c = 0; c < mesh.cellCount(); ++c) {
        if (!mesh.cellActive(c)) continue;
        const double e = mesh.cellYoungs()[static_cast<std::size_t>(c)];
        if (e == 24000) ++lesion;
        if (e != 24000 && e != 4000 && e != 3000) ++other;
    }
    EXPECT_EQ(other, 0);
    EXPECT_GE(lesion, 27);    // the 8 mm cube's 2 mm cells, less a layer at most
    vo.nearestValue = false;  // the trilinear blend between labels
    try {
        fem::voxelizeVolume(vol, vo);
        ADD_FAILURE() << "a blend of labels was looked up";
    } catch (const ValueError& e) {
        EXPECT_NE(std::string(e.what()).find("labels.csv: expected a row covering"),
                  std::string::npos)
            << e.what();
    }
}

// makeDeformableModel applies a setup's table: the body's elements carry the table's moduli
// and its material the table's Poisson ratio.
TEST(MaterialTable, TheSetupsTableReachesTheBody) {
    volume::PhantomSpec spec;
    spec.params.scene = volume::PhantomScene::Tumour;
    spec.voxelSize = 2e-3;
    const volume::Volume vol = volume::makePhantomVolume(spec);
    DeformableSetup setup;
    setup.supportFace = fem::BoxFace::yMax;
    setup.material.poissonRatio = 0.3;  // the table's 0.45 replaces it
    setup.materialTable = std::make_shared<const MaterialTable>(MaterialTable::builtInCt());
    const auto model = makeDeformableModel(vol, setup);
    EXPECT_EQ(model->model().material().poissonRatio, 0.45);
    int lesion = 0;
    for (const double e : model->model().mesh().cellYoungs()) {
        if (e == 19990) ++lesion;
        EXPECT_TRUE(e == 0 || e == 3250 || e == 3240 || e == 19990) << e;
    }
    EXPECT_GT(lesion, 0);
    // The bone phantom's bone cells do not take the whole mesh off the 1 kHz tick: auto keeps
    // it, as it does without the table (4,000 elements x 2 substeps).
    spec.params.scene = volume::PhantomScene::Bone;
    setup.autoSolver = true;
    SolverChoice choice;
    makeDeformableModel(volume::makePhantomVolume(spec), setup, &choice);
    EXPECT_EQ(choice.solver, DeformableSolver::wholeMeshExplicit) << choice.reason;
}

/// parse()'s refusal of @p text: its message, or "" when it was accepted.
std::string refusal(const std::string& text) {
    try {
        MaterialTable::parse(text, "bad.csv");
    } catch (const Error& e) {
        return e.what();
    }
    return "";
}

TEST(MaterialTable, BadTablesAreRefusedNamingTheFileLineAndRow) {
    const std::string header = "name,lo,hi,youngs_pa,poisson,density_kg_m3,source\n";
    const std::string fat = "fat,-200,-30,3000,0.45,1000,ref\n";
    struct Case {
        std::string text, message;
    };
    const std::vector<Case> cases = {
        {header + fat + "soft,-50,150,4000,0.45,1000,ref\n",
         "bad.csv line 3 (row 'soft') lo: expected a range that overlaps no other row's: at "
         "least -30, where line 2 (row 'fat') [-200, -30) ends, found -50"},
        {header + fat + "soft,-30,150,-5,0.45,1000,ref\n",
         "bad.csv line 3 (row 'soft') youngs_pa: expected a value in [1, 1e+12] Pa, found -5"},
        {header + fat + "soft,-30,150,0,0.45,1000,ref\n", "(row 'soft') youngs_pa: expected"},
        {header + fat + "soft,-30,150,nan,0.45,1000,ref\n", "youngs_pa: expected a value in "},
        {header + "soft,-30,150,4000,0.5,1000,ref\n",
         "bad.csv line 2 (row 'soft') poisson: expected a value in (-1, 0.5), found 0.5"},
        {header + "soft,-30,150,4000,-1.5,1000,ref\n", "(row 'soft') poisson: expected"},
        {header + "soft,-30,150,4000,0.45,0,ref\n",
         "(row 'soft') density_kg_m3: expected a value in [1, 100000] kg/m^3, found 0"},
        {header + fat + "soft,-30,150,4000,0.49,1000,ref\n",
         "bad.csv line 3 (row 'soft') poisson: expected 0.45, the Poisson ratio of line 2 (row "
         "'fat') (palp's solvers take one Poisson ratio per body"},
        {header + fat + "soft,-30,150,4000,0.45,1060,ref\n",
         "(row 'soft') density_kg_m3: expected 1000 kg/m^3, the density of line 2 (row 'fat')"},
        {"name,lo,hi,youngs_pa,poisson,colour,density_kg_m3,source\n",
         "bad.csv line 1 (header) column 6: expected one of name, lo, hi, label, youngs_pa, "
         "poisson, density_kg_m3, source, found 'colour'"},
        {"name,lo,youngs_pa,poisson,density_kg_m3,source\n", "found no 'hi'"},
        {header + "soft,-30,150,4000,0.45,1000\n",
         "bad.csv line 2: expected 7 fields (as the header), found 6"},
        {header + "soft,-30,abc,4000,0.45,1000,ref\n",
         "bad.csv line 2 (row 'soft') hi: expected a number, found 'abc'"},
        {header + "soft,-30,150,4000,0.45,1000,\n", "(row 'soft') source: expected"},
        {header + "soft,150,-30,4000,0.45,1000,ref\n", "(row 'soft') lo, hi: expected lo < hi"},
        {header + fat + "fat,-30,150,4000,0.45,1000,ref\n",
         "line 3 (row 'fat') name: expected a name no other row has"},
        {"name,label,youngs_pa,poisson,density_kg_m3,source\na,1,4000,0.45,1000,r\n"
         "b,1,5000,0.45,1000,r\n",
         "(row 'b') label: expected a label no other row has, found 1, the label of line 2"},
        {header, "bad.csv: expected at least one row after the header, found none"},
        {"# only a comment\n", "bad.csv: expected a header line and rows, found none"},
        {header + "soft,-30,150,4000,0.45,1000,\"unclosed\n", "expected a closing"},
    };
    for (const Case& c : cases) {
        const std::string m = refusal(c.text);
        EXPECT_NE(m.find(c.message), std::string::npos) << "table:\n" << c.text << "message: " << m;
    }
    // Quoted sources with commas, comments, blank lines, columns in any order: accepted.
    const MaterialTable ok = MaterialTable::parse(
        "\xEF\xBB\xBF# comment\n\nsource,name,hi,lo,youngs_pa,poisson,density_kg_m3\r\n"
        "\"Samani, 2007 \"\"fat\"\"\",fat,-30,-200,3250,0.45,1000\r\n",
        "ok.csv");
    ASSERT_EQ(ok.rows().size(), 1u);
    EXPECT_EQ(ok.rows()[0].source, "Samani, 2007 \"fat\"");
    EXPECT_EQ(ok.rows()[0].lo, -200);
    EXPECT_EQ(ok.rows()[0].line, 4);
    // A file that is not there.
    palp::test::TempDir tmp;
    EXPECT_THROW(MaterialTable::load(tmp / "missing.csv"), IoError);
    { std::ofstream(tmp / "t.csv") << header << fat; }
    EXPECT_EQ(MaterialTable::load(tmp / "t.csv").origin(), (tmp / "t.csv").string());
}

}  // namespace
}  // namespace palp::haptics
