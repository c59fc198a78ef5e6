// palp phantom: the thesis scenes (docs/algorithms.md section 9) as CT-like volumes or DICOM
// series.
#include <cstdint>
#include <cstdio>
#include <filesystem>
#include <memory>
#include <string>
#include <vector>

#include "commands.h"
#include "option_checks.h"
#include "palp/base/error.h"
#include "palp/volume/dicom.h"
#include "palp/volume/load.h"
#include "palp/volume/phantom.h"

namespace palp::tool {

namespace fs = std::filesystem;

namespace {
constexpr Bounds kInclusionRadius{volume::phantom_geometry::kTumourMinRadius,
                                  volume::phantom_geometry::kTumourMaxRadius, "m"};
}  // namespace

Command addPhantom(CLI::App& root) {
    struct Args {
        std::string scene;
        std::string output;
        std::string dicomDir;
        int quadrant = 0;
        std::string shape = "circle";
        int displacement = 0;
        double boneTiltDeg = 10;
        std::string profile = "linear";
        double widthMm = 10;
        double tanhSharpness = 3;
        double hardDepthMm = 15;
        double fatMm = 2;
        std::vector<double> inclusionCentreMm;  // empty: the default (0, 16, 0) mm
        double inclusionRadiusMm = 8;
        double voxelMm = 0.5;
        double noiseHu = 0;
        double blurMm = 0;
        int supersample = 1;
        std::uint64_t seed = 0;
        double marginMm = 5;
        double sliceSpacingMm = 0;
        std::vector<double> sliceGapsMm;
        double tiltDeg = 0;
    };
    auto args = std::make_shared<Args>();
    CLI::App* app = root.add_subcommand(
        "phantom",
        "Generate a thesis scene (avc, avcec, bone, stiffness, tumour) as a CT-like .vdb or DICOM "
        "series");
    app->add_option("scene", args->scene, "Scene: avc, avcec, bone, stiffness or tumour")
        ->required()
        ->check(CLI::IsMember({"avc", "avcec", "bone", "stiffness", "tumour"}));
    auto* out = app->add_option("-o,--output", args->output, "Output .vdb file");
    auto* dicom = app->add_option("--dicom-dir", args->dicomDir,
                                  "Write a DICOM CT series into this new directory");
    out->excludes(dicom);
    app->add_option("--quadrant", args->quadrant,
                    "avc: quadrant of the hidden box, 0-3 (bit 0: +x, bit 1: +z)")
        ->check(integerIn(0, 3));
    app->add_option("--shape", args->shape, "avcec: plate outline")
        ->check(CLI::IsMember({"circle", "triangle", "rectangle", "hexagon", "pentagon"}));
    app->add_option("--displacement", args->displacement,
                    "bone: -1 right side (x<0) closer to the surface, 0 level, 1 left side closer")
        ->check(integerIn(-1, 1));
    app->add_option("--bone-tilt", args->boneTiltDeg,
                    "bone: slab tilt for displacement +-1, degrees")
        ->check(within(bounds::kTiltAngle, kDegrees));
    app->add_option("--profile", args->profile, "stiffness: CL transition profile")
        ->check(CLI::IsMember({"linear", "cosine", "tanh"}));
    app->add_option("--width", args->widthMm, "stiffness: CL transition width, mm")
        ->check(within(bounds::kLength, kMm));
    app->add_option("--tanh-a", args->tanhSharpness, "stiffness: sharpness of the tanh profile")
        ->check(within(bounds::kShapeFactor));
    app->add_option("--hard-depth", args->hardDepthMm,
                    "stiffness: CP depth below which the box is harder, mm")
        ->check(within(bounds::kSpan, kMm));
    auto* inclusionCentre =
        app->add_option("--inclusion-centre", args->inclusionCentreMm,
                        "tumour: centre x,y,z of the spherical inclusion, mm (y: depth below the "
                        "surface; default 0,16,0)")
            ->delimiter(',')
            ->expected(3)
            ->check(within(bounds::kPosition, kMm));
    auto* inclusionRadius = app->add_option("--inclusion-radius", args->inclusionRadiusMm,
                                            "tumour: radius of the inclusion, mm")
                                ->check(within(kInclusionRadius, kMm));
    app->add_option("--fat", args->fatMm, "Fat layer thickness under the surface, mm (0 for none)")
        ->check(within(bounds::kSpan, kMm));
    app->add_option("--voxel-size", args->voxelMm, "Voxel edge (and DICOM pixel spacing), mm")
        ->check(within(bounds::kSpacing, kMm));
    app->add_option("--noise", args->noiseHu, "Gaussian noise standard deviation, HU")
        ->check(within(bounds::kVolumeSpread, {1, "HU"}));
    app->add_option("--blur", args->blurMm, "Gaussian partial-volume blur standard deviation, mm")
        ->check(within(bounds::kSpan, kMm));
    app->add_option("--supersample", args->supersample,
                    "Sub-samples per pixel edge (n^3 per pixel), 1-8")
        ->check(integerIn(1, 8));
    app->add_option("--seed", args->seed, "Noise seed (the same seed gives identical output)")
        ->check(integerIn(0, INT64_MAX));
    app->add_option("--margin", args->marginMm, "Air around the scene, mm")
        ->check(within(bounds::kSpan, kMm));
    app->add_option(
           "--slice-spacing", args->sliceSpacingMm,
           "DICOM: gap between slices along the slice normal, mm (default: the voxel size)")
        ->check(within(bounds::kSpacing, kMm));
    app->add_option("--slice-gaps", args->sliceGapsMm,
                    "DICOM: uneven gaps along the normal, mm, used cyclically")
        ->delimiter(',')
        ->check(within(bounds::kSpacing, kMm));
    app->add_option("--tilt", args->tiltDeg, "DICOM: gantry tilt, degrees")
        ->check(within(bounds::kTiltAngle, kDegrees));
    return {
        app, [args, out, dicom, inclusionCentre, inclusionRadius]() -> int {
            if (out->count() == 0 && dicom->count() == 0) {
                throw ValueError("phantom: expected -o OUT.vdb or --dicom-dir DIR, found neither");
            }
            const bool toDicom = dicom->count() > 0;
            if (!toDicom &&
                (args->tiltDeg != 0 || args->sliceSpacingMm != 0 || !args->sliceGapsMm.empty())) {
                throw ValueError(
                    "phantom: expected --tilt, --slice-spacing and --slice-gaps only with "
                    "--dicom-dir, "
                    "found them with -o");
            }
            volume::PhantomSpec spec;
            volume::PhantomParams& p = spec.params;
            p.scene = volume::parseScene(args->scene);
            p.quadrant = args->quadrant;
            p.shape = volume::parseShape(args->shape);
            p.displacement = args->displacement;
            p.boneTiltDeg = args->boneTiltDeg;
            p.profile = volume::parseProfile(args->profile);
            p.transitionWidth = args->widthMm * 1e-3;
            p.tanhSharpness = args->tanhSharpness;
            p.hardDepth = args->hardDepthMm * 1e-3;
            p.fatThickness = args->fatMm * 1e-3;
            for (const CLI::Option* o : {inclusionCentre, inclusionRadius}) {
                if (o->count() > 0 && p.scene != volume::PhantomScene::Tumour) {
                    throw ValueError("phantom " + o->get_name() +
                                     ": expected the tumour scene, found " + args->scene);
                }
            }
            if (args->inclusionCentreMm.size() == 3) {
                p.inclusionCentre =
                    Eigen::Vector3d(args->inclusionCentreMm[0], args->inclusionCentreMm[1],
                                    args->inclusionCentreMm[2]) *
                    1e-3;
            }
            p.inclusionRadius = args->inclusionRadiusMm * 1e-3;
            try {
                const volume::Phantom check(p);
            } catch (const ValueError& e) {
                // The library speaks of its fields; name the options that set them.
                if (std::string(e.what()).find("phantom inclusion") == std::string::npos) throw;
                throw ValueError(std::string("--inclusion-centre, --inclusion-radius: ") +
                                 e.what());
            }
            spec.voxelSize = args->voxelMm * 1e-3;
            spec.noiseSigmaHu = args->noiseHu;
            spec.blurSigma = args->blurMm * 1e-3;
            spec.supersample = args->supersample;
            spec.seed = args->seed;
            spec.margin = args->marginMm * 1e-3;

            if (!toDicom) {
                const fs::path path(args->output);
                const fs::path dir = path.has_parent_path() ? path.parent_path() : fs::path(".");
                std::error_code ec;
                if (!fs::is_directory(dir, ec)) {
                    throw IoError(path.string() + ": expected an existing directory '" +
                                  dir.string() + "' for the output, found none");
                }
                const volume::Volume vol = volume::makePhantomVolume(spec);
                volume::save(vol, path);
                if (!globals().quiet) {
                    std::printf("palp phantom: wrote %s: %s, voxel %.4g mm, %llu active voxels\n",
                                path.c_str(), vol.info.sourceDescription.c_str(),
                                vol.voxelSize() * 1e3,
                                static_cast<unsigned long long>(vol.grid->activeVoxelCount()));
                }
                return 0;
            }
            volume::SliceGeometry geometry;
            geometry.pixelSpacing = spec.voxelSize;
            geometry.sliceSpacing =
                args->sliceSpacingMm > 0 ? args->sliceSpacingMm * 1e-3 : spec.voxelSize;
            for (double g : args->sliceGapsMm) geometry.sliceGaps.push_back(g * 1e-3);
            geometry.tiltDeg = args->tiltDeg;
            const volume::SliceStack stack = volume::makePhantomSlices(spec, geometry);
            volume::DicomWriteOptions options;
            options.modality = "CT";
            options.seriesDescription = "palp phantom " + volume::Phantom(p).description();
            options.gantryTiltDeg = args->tiltDeg;
            options.clampToStorage = true;  // noise on air below -1024 HU clips, as on a scanner
            const fs::path dirPath(args->dicomDir);
            volume::writeDicomSeries(stack, dirPath, options);
            if (!globals().quiet) {
                const volume::Slice& s = stack.slices.front();
                std::printf("palp phantom: wrote %s: %zu CT slices of %dx%d pixels, %s\n",
                            dirPath.c_str(), stack.slices.size(), s.cols, s.rows,
                            stack.info.sourceDescription.c_str());
            }
            return 0;
        }};
}

}  // namespace palp::tool
