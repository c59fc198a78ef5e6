// A C++ program on palp's installed modules (palp::volume, palp::haptics), built by
// tools/test_package.sh with find_package(palp CONFIG): a scan read from a file (an NRRD it
// writes) and a missing one refused as palp::IoError, the AVC phantom as a volume, a scene,
// a simulated VC press held 4 mm deep into the skin, stepped offline; the force must push out
// of the skin with |F| = k D, and palp's exceptions must cross the library boundary as
// palp::ValueError. Exits non-zero, saying why, on any failure.
#include <chrono>
#include <cmath>
#include <cstdio>
#include <exception>
#include <filesystem>
#include <fstream>
#include <memory>
#include <string>

#include "palp/base/error.h"
#include "palp/haptics/devices/simulated_device.h"
#include "palp/haptics/devices/trajectory.h"
#include "palp/haptics/session.h"
#include "palp/studies/offline_run.h"
#include "palp/volume/load.h"
#include "palp/volume/phantom.h"

namespace {

int failures = 0;

void expect(bool ok, const char* what) {
    if (!ok) {
        std::fprintf(stderr, "consumer_cpp: failed: %s\n", what);
        ++failures;
    }
}

/// An 8 x 8 x 8 int16 NRRD (1 mm voxels, LPS origin (10, -20, 30) mm, 100 HU) read with
/// palp::volume::load: 1 mm voxels, world bounds around the voxel centres' box (7 mm) plus at
/// most the resampler's one-voxel border.
void readAScan() {
    namespace fs = std::filesystem;
    const fs::path path =
        fs::temp_directory_path() /
        ("palp_consumer_" +
         std::to_string(std::chrono::steady_clock::now().time_since_epoch().count()) + ".nrrd");
    {
        std::ofstream out(path, std::ios::binary);
        out << "NRRD0004\ntype: short\ndimension: 3\nspace: left-posterior-superior\n"
               "sizes: 8 8 8\nspace directions: (1,0,0) (0,1,0) (0,0,1)\n"
               "space origin: (10,-20,30)\nendian: little\nencoding: raw\n\n";
        for (int i = 0; i < 8 * 8 * 8; ++i) out.write("\x64\x00", 2);  // 100, little-endian
    }
    const palp::volume::Volume scan = palp::volume::load({path});
    fs::remove(path);
    expect(std::abs(scan.voxelSize() - 1e-3) < 1e-12, "the scan's 1 mm voxels");
    const auto bounds = scan.worldBounds();
    const double centre[3] = {0.0135, -0.0165, 0.0335};  // origin + 3.5 mm, m
    for (int a = 0; a < 3; ++a) {
        const double lo = bounds.min()[a], hi = bounds.max()[a];
        expect(std::abs(0.5 * (lo + hi) - centre[a]) < 1e-9, "the scan where its header puts it");
        expect(hi - lo > 7e-3 - 1e-9 && hi - lo < 9e-3 + 1e-9, "the scan's extent");
    }
    std::printf("consumer_cpp: read %s: x from %.1f to %.1f mm\n", path.c_str(),
                bounds.min()[0] * 1e3, bounds.max()[0] * 1e3);
    try {
        palp::volume::load({path});
        expect(false, "a missing file is refused");
    } catch (const palp::IoError& e) {
        expect(std::string(e.what()).find(path.string()) != std::string::npos,
               "the I/O error names the file");
    }
}

void run() {
    readAScan();
    namespace pv = palp::volume;
    namespace ph = palp::haptics;

    pv::PhantomSpec spec;
    spec.params.scene = pv::parseScene("avc");
    spec.voxelSize = 1e-3;
    const pv::Volume volume = pv::makePhantomVolume(spec);
    expect(volume.grid && volume.grid->activeVoxelCount() > 0, "the phantom has voxels");
    expect(std::abs(volume.voxelSize() - 1e-3) < 1e-12, "1 mm voxels");

    ph::SceneOptions sceneOptions;
    sceneOptions.surfaceIso = -500;
    const std::shared_ptr<ph::Scene> scene = ph::Scene::fromVolume(volume, sceneOptions);

    ph::SessionParams params;
    params.coupling.mode = ph::CouplingMode::VC;
    params.coupling.baseStiffness = 300;
    params.proxy.staticFriction = 0;
    params.proxy.dynamicFriction = 0;
    ph::PressTrajectory press;
    press.start = Eigen::Vector3d(0.002, -0.005, 0.001);  // 5 mm above the skin (y = 0)
    press.direction = Eigen::Vector3d(0, 1, 0);           // depth is +y
    press.depthM = 0.009;                                 // 4 mm into the skin
    press.pressSeconds = 0.4;
    press.holdSeconds = 1.0;
    const ph::DeviceSpec* touchX = ph::findDeviceSpec("3D Systems Touch X");
    expect(touchX != nullptr, "the Touch X is in palp's device table");
    if (!touchX) return;
    ph::SimulatedDevice device(*touchX, ph::Trajectory(press), ph::HandModel{},
                               params.servo.periodSeconds);
    ph::Session session(scene, device, params);
    const auto snapshots = ph::runOffline(session, 1000, 100);  // 0.6 s into the hold
    expect(snapshots.size() == 11, "ticks 0, 100, ..., 900 and the last one kept");
    if (snapshots.empty()) return;
    const ph::Snapshot& s = snapshots.back();
    std::printf("consumer_cpp: tick %llu: proxy y %.3f mm, probe y %.3f mm, force y %.4f N\n",
                static_cast<unsigned long long>(s.tick), s.proxy.y() * 1e3, s.probe.y() * 1e3,
                s.force.y());
    expect(s.tick == 999, "the last snapshot is tick 999");
    expect(std::abs(s.proxy.y()) < 0.5e-3, "the proxy on the skin");
    expect(s.probe.y() > s.proxy.y() + 1e-3, "the probe more than 1 mm inside");
    expect(s.force.y() < -0.3, "the force pushes out of the skin");
    expect(std::abs(s.force.norm() - 300.0 * s.distance) < 1e-9, "|F| = k D");

    // Exceptions thrown inside libpalp_volume are caught here by their type.
    try {
        pv::parseScene("no-such-scene");
        expect(false, "parseScene refuses an unknown name");
    } catch (const palp::ValueError& e) {
        expect(std::string(e.what()).find("no-such-scene") != std::string::npos,
               "the message names the value");
    }
}

}  // namespace

int main() {
    try {
        run();
    } catch (const std::exception& e) {
        std::fprintf(stderr, "consumer_cpp: %s\n", e.what());
        return 1;
    }
    if (failures) {
        std::fprintf(stderr, "consumer_cpp: %d failure(s)\n", failures);
        return 1;
    }
    std::printf("consumer_cpp: ok\n");
    return 0;
}
