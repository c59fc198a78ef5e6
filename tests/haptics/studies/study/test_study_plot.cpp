// The psychometric plot: valid PNG, SVG (parsed by Python's XML reader) and PDF files with the
// panel's content (title, axes with units, one disc per level), written whole; and the touch
// modes' paths over the stiffness phantom.
#include <gtest/gtest.h>

#include <cstdlib>
#include <random>

#include "palp/base/error.h"
#include "palp/perception/psychometric_fit.h"
#include "palp/studies/psychometric_plot.h"
#include "palp/studies/touch_modes.h"
#include "palp/volume/phantom.h"
#include "study_fixture.h"

namespace palp::haptics {
namespace {

using namespace study_test;

/// A condition's results from a known Weibull observer (alpha 10 %, beta 2) at six levels.
ConditionResult knownResult(const std::string& name, std::uint64_t seed) {
    perception::PsychometricFunction truth;
    truth.alpha = 10;
    truth.beta = 2;
    std::mt19937_64 rng(seed);
    ConditionResult r;
    r.name = name;
    r.target = std::sqrt(0.5);
    for (double level : {2.0, 4.0, 8.0, 12.0, 18.0, 30.0}) {
        perception::ResponseBlock b{level, 0, 10 + static_cast<int>(level)};
        std::bernoulli_distribution yes(perception::psi(truth, level));
        for (int i = 0; i < b.trials; ++i) b.correct += yes(rng) ? 1 : 0;
        r.blocks.push_back(b);
        r.trials += b.trials;
    }
    perception::FitOptions fo;
    r.fit = perception::fitPsychometric(r.blocks, fo);
    r.fitThreshold = perception::thresholdAt(r.fit->function, r.target);
    perception::BootstrapOptions bo;
    bo.samples = 100;
    bo.thresholdLevels = {r.target};
    auto br = perception::bootstrapPsychometric(r.blocks, *r.fit, fo, bo);
    r.fitInterval = br.thresholds.front();
    r.bootstrapFits = br.fits;
    r.procedureThreshold = 9.5;
    return r;
}

TEST(PsychometricPlot, WritesValidPngSvgAndPdf) {
    const fs::path d = tempDir("plot");
    const std::vector<ConditionResult> results{knownResult("CP", 1), knownResult("DP", 2)};
    writePsychometricPlot(d / "psy", results, "palp study test");
    const std::string png = slurp(d / "psy.png"), svg = slurp(d / "psy.svg"),
                      pdf = slurp(d / "psy.pdf");
    ASSERT_GT(png.size(), 8u);
    EXPECT_EQ(png.substr(0, 8), std::string("\x89PNG\r\n\x1a\n", 8));
    // IHDR: 2 px a point, two panels of 330 x 270 points plus the title and legend rows.
    const auto be32 = [&](std::size_t at) {
        return (static_cast<unsigned>(static_cast<unsigned char>(png[at])) << 24) |
               (static_cast<unsigned>(static_cast<unsigned char>(png[at + 1])) << 16) |
               (static_cast<unsigned>(static_cast<unsigned char>(png[at + 2])) << 8) |
               static_cast<unsigned>(static_cast<unsigned char>(png[at + 3]));
    };
    EXPECT_EQ(be32(16), 2u * 660u);
    EXPECT_EQ(be32(20), 2u * 310u);
    EXPECT_GT(png.size(), 20000u);  // drawn, not blank
    EXPECT_EQ(pdf.substr(0, 5), "%PDF-");
    EXPECT_NE(pdf.find("%%EOF"), std::string::npos);
    EXPECT_GT(pdf.size(), 5000u);
    EXPECT_NE(svg.find("<svg"), std::string::npos);
    const std::string cmd =
        "/usr/bin/python3 -c \"import sys, xml.etree.ElementTree as E; "
        "r = E.parse(sys.argv[1]).getroot(); "
        "sys.exit(0 if r.tag.endswith('svg') else 1)\" " +
        (d / "psy.svg").string();
    EXPECT_EQ(std::system(cmd.c_str()), 0) << "the SVG does not parse as XML";
    // No temporary left beside the figures.
    int files = 0;
    for (const auto& e : fs::directory_iterator(d)) files += e.is_regular_file() ? 1 : 0;
    EXPECT_EQ(files, 3);
    EXPECT_THROW(writePsychometricPlot(d / "none", {}, "empty"), ValueError);
    EXPECT_THROW(writePsychometricPlot(d / "no_such_dir" / "psy", results, "x"), IoError);
}

TEST(TouchModes, EachModeTouchesItsObjectTheWayPaperIIIDescribes) {
    namespace geo = volume::phantom_geometry;
    for (TouchMode m : {TouchMode::ContinuousPressure, TouchMode::DiscontinuousPressure,
                        TouchMode::LateralSweep}) {
        EXPECT_EQ(parseTouchMode("t", touchModeName(m)), m);
        const TouchPath p = touchPath(m);
        const double cx = volume::Phantom::stiffnessBoxCentreX(touchBox(m));
        Eigen::Vector3d pos, vel;
        double minX = 1, maxX = -1, deepest = -1;
        for (double t = 0; t <= p.seconds; t += 1e-3) {
            sampleTrajectory(p.trajectory, t, pos, vel);
            minX = std::min(minX, pos.x());
            maxX = std::max(maxX, pos.x());
            deepest = std::max(deepest, pos.y());
        }
        const TouchParams d = touchDefaults(m);
        EXPECT_NEAR(deepest, d.depthM, 1e-6) << touchModeName(m);
        if (m == TouchMode::LateralSweep) {
            // Across the CL box's transition (its centre) in both directions, inside the box.
            EXPECT_NEAR(minX, cx - 0.015, 2e-4);
            EXPECT_NEAR(maxX, cx + 0.015, 2e-4);
            EXPECT_LT(maxX - minX, geo::kStiffBoxWidth);
        } else {
            EXPECT_NEAR(minX, cx, 1e-12);  // straight along the normal
            EXPECT_NEAR(maxX, cx, 1e-12);
        }
    }
    EXPECT_EQ(touchBox(TouchMode::DiscontinuousPressure), 0);  // DP: uniformly harder
    EXPECT_EQ(touchBox(TouchMode::ContinuousPressure), 1);     // CP: harder below a depth
    EXPECT_EQ(touchBox(TouchMode::LateralSweep), 2);           // CL: the transition
    EXPECT_LT(thesisWeberFraction(TouchMode::ContinuousPressure),
              thesisWeberFraction(TouchMode::DiscontinuousPressure));
    EXPECT_LT(thesisWeberFraction(TouchMode::DiscontinuousPressure),
              thesisWeberFraction(TouchMode::LateralSweep));
    EXPECT_THROW(parseTouchMode("--trajectory", "rub"), ValueError);
    EXPECT_THROW(touchPath(TouchMode::LateralSweep, {0.05, 0, 0.2}), ValueError);  // 50 mm deep
}

}  // namespace
}  // namespace palp::haptics
