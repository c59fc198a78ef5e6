// A C++ program on palp's installed modules (palp::volume, palp::haptics), built by
// tools/test_package.sh with find_package(palp CONFIG): the AVC phantom as a volume, a scene,
// a simulated VC press held 4 mm deep into the skin, stepped offline; the force must push out
// of the skin with |F| = k D, and palp's exceptions must cross the library boundary as
// palp::ValueError. Exits non-zero, saying why, on any failure.
#include <cmath>
#include <cstdio>
#include <exception>
#include <memory>
#include <string>

#include "palp/base/error.h"
#include "palp/haptics/offline_run.h"
#include "palp/haptics/session.h"
#include "palp/haptics/simulated_device.h"
#include "palp/haptics/trajectory.h"
#include "palp/volume/phantom.h"

namespace {

int failures = 0;

void expect(bool ok, const char* what) {
    if (!ok) {
        std::fprintf(stderr, "consumer_cpp: failed: %s\n", what);
        ++failures;
    }
}

void run() {
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
