#pragma once
/// @file
/// The command line of `palp palpate`: its options and the checks made before any work.

#include <CLI/CLI.hpp>
#include <cmath>
#include <cstdint>
#include <string>
#include <vector>

#include "palp/haptics/devices/device.h"
#include "palp/haptics/servo_loop.h"

namespace palp::tool {

/// How the servo thread runs (palpate --realtime, serve, study --device-listen).
struct ServoArgs {
    int cpu = -1;                     // --servo-cpu: the servo thread's CPU (-1: the last allowed)
    int priority = 80;                // --servo-priority: SCHED_FIFO 1..99 (0: none)
    bool noRealtimePriority = false;  // --no-realtime-priority: SCHED_OTHER (priority 0)
    bool lockMemory = false;          // --mlock: mlockall before the servo loop starts
    bool shareCpu = false;            // --servo-share-cpu: other threads keep the servo's CPU

    /// The servo thread's CPU, priority (`noRealtimePriority ? 0 : priority`), memory lock and
    /// CPU reservation (ServoConfig::reserveCpu unless shareCpu) onto @p config.
    void applyTo(haptics::ServoConfig& config) const {
        config.cpu = cpu;
        config.priority = noRealtimePriority ? 0 : priority;
        config.lockMemory = lockMemory;
        config.reserveCpu = !shareCpu;
    }
};

/// Everything `palp palpate` reads from its command line (mm, mm/s, HU, N/m as the options say).
struct PalpateArgs {
    std::string file;
    std::string phantom;
    int quadrant = 0;
    std::string shape = "circle";
    int displacement = 0;
    std::string profile = "linear";
    double voxelMm = 1;
    double noiseHu = 0;
    std::uint64_t seed = 0;
    std::string mode, source;
    double kBase = NAN, kMax = NAN, lMaxMm = NAN, lRefMm = NAN, mMax = NAN;
    double threshold = NAN, sigmaPerMm = NAN, sigmaThreshold = NAN, tauStop = NAN;
    double stepMm = NAN, damping = NAN;
    double sobelAngle = NAN, surfaceOffsetMm = NAN, maxRayTilt = NAN;
    int ring = -1;
    double surfaceIso = -500;
    double muStatic = 0.5, muDynamic = NAN;  // NAN: 0.3, or --mu-static when lower
    bool passivityControl = false;
    std::string trajectory = "raster";
    std::vector<double> centreMm;
    std::vector<double> extentMm;
    double spacingMm = 2;
    double speedMmps = NAN;
    double depthMm = 4;
    std::string pressAxis = "+y";  ///< used when given (CheckedOptions::pressAxis)
    std::string followSkin = "auto";
    std::string sweepAxis;
    double radiusMm = 10;
    double frequencyHz = 1;
    int passes = 4;
    double holdSeconds = 0.5;
    bool realtime = false;
    bool fast = false;
    double seconds = 0;  // offline: simulated s; --realtime: wall-clock s (0: the path's length)
    ServoArgs servo;     // --servo-cpu, --servo-priority, --no-realtime-priority, --mlock, ...
    std::string trace;
    std::string map;
    std::string mapQuantity = "stiffness";
    std::string mapAt = "proxy";
    double mapPixelMm = 0;
    /// --map-underlay: auto (skin-depth on a rigid scan, none on a phantom or deformable
    /// tissue), skin-depth, mip or none
    std::string mapUnderlay = "auto";
    bool grey = false;
    std::string device = "3D Systems Touch";
    bool json = false;
    bool deformable = false;
    double femCellMm = 5;
    double youngKpa = 5;
    double poisson = 0.45;
    double femAlpha = 60;
    double femBeta = 0;
    double filterMm = 3;
    double recontactMs = 15;        // haptics::RecontactParams::seconds, in ms
    double recontactRiseNps = 100;  // haptics::RecontactParams::riseNps
    double boneHu = 500;
    double tissueHu = -200;
    std::string insideBone = "drop";  ///< --inside-bone: drop or keep tissue enclosed by bone
    std::string femSolver = "auto";
    std::string material = "linear";  ///< --material: linear or neo-hookean
    std::string materialTable;        ///< --material-table: "ct" or a file; empty: none
    int primaryNodes = 60;
    double secondaryHz = 100;
    int lod = 0;  ///< 0: haptics::autoRegionsLod (2 where the cell counts are even, else 1; 4 on
                  ///< large faces)
    /// --error-budget: "off" or a percentage (palpate/error_budget.h); default the normal-pressure
    /// stiffness JND (haptics::kNormalPressureJndPercent).
    std::string errorBudget = "5.23";
    std::string errorTable;  ///< --error-table: a table file; empty: the built-in one
};

/// The options checked against the scene: each scene option belongs to one phantom (or any), the
/// FEM options to --deformable.
struct CheckedOptions {
    CLI::Option* quadrant = nullptr;
    CLI::Option* shape = nullptr;
    CLI::Option* displacement = nullptr;
    CLI::Option* profile = nullptr;
    CLI::Option* voxel = nullptr;
    CLI::Option* noise = nullptr;
    CLI::Option* seed = nullptr;
    std::vector<CLI::Option*> fem;
    /// The uniform tissue's modulus and ratio, which --material-table replaces.
    CLI::Option *youngKpa = nullptr, *poisson = nullptr;
    CLI::Option* pressAxis = nullptr;  ///< given or left to palp (the skin's best side on a scan)
    /// Given or left to palp (a scan without HU takes scanDefaults()).
    CLI::Option *surfaceIso = nullptr, *tissueHu = nullptr, *boneHu = nullptr, *threshold = nullptr;
};

/// Registers every option of `palp palpate` on @p app, bound to @p args; @p checked receives the
/// options checkPalpateOptions() checks against the scene. @p args and @p checked must outlive
/// the parse.
void addPalpateOptions(CLI::App* app, PalpateArgs& args, CheckedOptions& checked);

/// Registers --servo-cpu, --servo-priority, --no-realtime-priority, --mlock and
/// --servo-share-cpu (palpate and serve), bound to @p servo.
void addServoOptions(CLI::App* app, ServoArgs& servo);

/// Checks a FILE or a phantom, scene options only with their phantom, FEM options only with
/// --deformable, --material neo-hookean not on the regions, --material-table without
/// --young-kpa or --poisson, the device class, output directories existing, usable depth, spacing
/// and time; returns the device class named by --device (never null).
/// @throw palp::ValueError naming the option; palp::IoError naming a missing directory.
const haptics::DeviceSpec* checkPalpateOptions(const PalpateArgs& args,
                                               const CheckedOptions& checked);

}  // namespace palp::tool
