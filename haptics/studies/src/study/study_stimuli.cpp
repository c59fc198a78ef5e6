// One interval of a stiffness study: a session on the stiffness phantom, the hand on its touch
// path, and what it felt.
#include "palp/studies/study_stimuli.h"

#include <cmath>
#include <string>

#include "../in_contact.h"
#include "palp/base/error.h"
#include "palp/haptics/devices/simulated_device.h"
#include "palp/haptics/rendering/coupling_defaults.h"
#include "palp/studies/offline_run.h"

namespace palp::haptics {

namespace {
constexpr double kPeriod = 1e-3;
constexpr double kBinM = 0.5e-3;
}  // namespace

StudyStimuli::StudyStimuli(StudySpec spec) : mSpec(std::move(spec)) {
    for (const StudyCondition& c : mSpec.conditions) {
        try {
            (void)touchPath(c.touch, {c.depthM, c.speedMps});
        } catch (const ValueError& e) {
            throw ValueError(mSpec.source + ": condition " + c.name + ": " + e.what());
        }
    }
}

StudyStimuli::~StudyStimuli() = default;

std::shared_ptr<const Scene> StudyStimuli::scene(volume::TransitionProfile profile) {
    const int key = static_cast<int>(profile);
    auto it = mScenes.find(key);
    if (it != mScenes.end()) return it->second;
    volume::PhantomSpec spec;
    spec.params.scene = volume::PhantomScene::Stiffness;
    spec.params.profile = profile;
    spec.voxelSize = mSpec.voxelM;
    spec.noiseSigmaHu = 10;  // as the virtual experiments' phantoms (test_experiments)
    spec.seed = mSpec.seed;
    std::shared_ptr<Scene> s = Scene::fromVolume(volume::makePhantomVolume(spec));
    s->commit();
    mScenes.emplace(key, s);
    return s;
}

CouplingParams StudyStimuli::coupling(int condition, double levelPercent) const {
    CouplingParams c = sceneCouplingDefaults(volume::PhantomScene::Stiffness);
    c.mode = mSpec.conditions.at(static_cast<std::size_t>(condition)).mode;
    const double factor = 1 + levelPercent / 100;
    c.baseStiffness = mSpec.referenceStiffnessNpm * factor;
    // The clamp scales with the stimulus so that it never flattens a difference.
    c.maxStiffness = c.baseStiffness * c.maxMultiplier;
    return c;
}

SessionParams StudyStimuli::sessionParams(int condition, double levelPercent) const {
    SessionParams params;
    params.coupling = coupling(condition, levelPercent);
    params.servo.periodSeconds = kPeriod;
    params.proxy.staticFriction = mSpec.friction;
    params.proxy.dynamicFriction = mSpec.friction;
    return params;
}

std::shared_ptr<const Scene> StudyStimuli::sceneFor(int condition) {
    if (condition < 0 || condition >= static_cast<int>(mSpec.conditions.size()))
        throw ValueError("study stimuli: condition " + std::to_string(condition) + " out of range");
    return scene(mSpec.conditions[static_cast<std::size_t>(condition)].profile);
}

IntervalFelt StudyStimuli::run(int condition, double levelPercent, std::vector<Snapshot>* trace) {
    const StudyCondition& c = mSpec.conditions[static_cast<std::size_t>(condition)];
    const TouchPath path = touchPath(c.touch, {c.depthM, c.speedMps});
    const DeviceSpec* device = findDeviceSpec(mSpec.device);
    if (device == nullptr)
        throw ValueError(mSpec.source + ": device: unknown '" + mSpec.device + "'");
    const SessionParams params = sessionParams(condition, levelPercent);
    SimulatedDevice hand(*device, path.trajectory, HandModel{}, kPeriod);
    Session session(scene(c.profile), hand, params);
    const auto ticks = static_cast<std::uint64_t>(std::ceil(path.seconds / kPeriod));
    std::vector<Snapshot> snaps = runOffline(session, ticks);
    ++mSessionsRun;
    IntervalFelt f;
    double sumK = 0, sumF = 0;
    std::map<long, std::pair<double, int>> bins;
    for (const Snapshot& s : snaps) {
        if (s.timeSeconds < path.pressedFrom || !detail::inContact(s)) continue;
        const double force = s.force.norm();
        sumK += s.stiffness;
        sumF += force;
        f.maxForceN = std::max(f.maxForceN, force);
        ++f.contactTicks;
        if (c.touch == TouchMode::LateralSweep) {
            auto& b = bins[std::lround(s.proxy.dot(path.axis) / kBinM)];
            b.first += s.stiffness;
            b.second += 1;
        }
    }
    if (f.contactTicks == 0) {
        throw ValueError(mSpec.source + ": condition " + c.name +
                         ": the simulated hand never touched the phantom (depth " +
                         std::to_string(c.depthM * 1e3) + " mm)");
    }
    f.meanStiffnessNpm = sumK / f.contactTicks;
    f.meanForceN = sumF / f.contactTicks;
    for (const auto& [bin, v] : bins) {
        f.profileM.push_back(static_cast<double>(bin) * kBinM);
        f.profileNpm.push_back(v.first / v.second);
    }
    if (trace) *trace = std::move(snaps);
    return f;
}

const IntervalFelt& StudyStimuli::feel(int condition, double levelPercent,
                                       std::vector<Snapshot>* trace) {
    if (condition < 0 || condition >= static_cast<int>(mSpec.conditions.size()))
        throw ValueError("study stimuli: condition " + std::to_string(condition) + " out of range");
    if (!(levelPercent >= 0 && levelPercent <= 1000))
        throw ValueError("study stimuli: expected a level in [0, 1000] %, found " +
                         std::to_string(levelPercent));
    const auto key = std::make_pair(condition, levelPercent);
    auto it = mFelt.find(key);
    if (it != mFelt.end() && trace == nullptr) return it->second;
    IntervalFelt f = run(condition, levelPercent, trace);
    return mFelt.insert_or_assign(key, std::move(f)).first->second;
}

}  // namespace palp::haptics
