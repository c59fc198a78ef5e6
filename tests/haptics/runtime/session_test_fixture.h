#pragma once
// The Session tests' fixture (test_session*.cpp): the AVC phantom scene built once per suite,
// the parameters every test starts from, the three coupling modes and the per-tick safety check.

#include <gtest/gtest.h>

#include <array>
#include <memory>

#include "palp/haptics/session.h"
#include "palp/volume/phantom.h"
#include "session_fixtures.h"

namespace palp::haptics::sfix {

using fixtures::at;
using fixtures::kT;
using fixtures::PathDevice;
using fixtures::touchX;

// The AVC phantom (surface at y = 0, depth +y; rigid plate at y in [10, 12] mm over x, z in
// +-30 mm), 1 mm voxels, skin surface at -500 HU and hard meshes at 500 HU. Built once.
class SessionTest : public ::testing::Test {
  protected:
    static void SetUpTestSuite() { fixtures::buildAvcScene(sVolume, sScene); }
    static void TearDownTestSuite() {
        sScene.reset();
        delete sVolume;
        sVolume = nullptr;
    }
    static SessionParams params(CouplingMode mode, RaySource source = RaySource::VolumeFirstHit) {
        SessionParams p;
        p.coupling.mode = mode;
        p.coupling.source = source;
        p.coupling.baseStiffness = 300;
        p.coupling.maxStiffness = 1400;
        p.proxy.staticFriction = 0;
        p.proxy.dynamicFriction = 0;
        return p;
    }
    inline static volume::Volume* sVolume = nullptr;
    inline static std::shared_ptr<Scene> sScene;
};

inline constexpr std::array<CouplingMode, 3> kModes = {CouplingMode::VC, CouplingMode::AVC,
                                                       CouplingMode::AVCEC};

// Every tick: finite force, within the device maximum.
inline void expectSafe(const Snapshot& s, const DeviceSpec& spec) {
    ASSERT_TRUE(s.force.allFinite()) << "tick " << s.tick;
    ASSERT_LE(s.force.norm(), spec.maxForceN * (1 + 1e-12)) << "tick " << s.tick;
}

}  // namespace palp::haptics::sfix
