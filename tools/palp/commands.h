#pragma once
/// @file
/// The palp command's subcommands. Each registers itself on the CLI11 app and runs when chosen.

#include <CLI/CLI.hpp>
#include <Eigen/Core>
#include <filesystem>
#include <functional>
#include <string>
#include <vector>

namespace palp::tool {

/// A registered subcommand: its CLI11 node and what to run when it was given.
struct Command {
    CLI::App* app = nullptr;
    std::function<int()> run;
};

/// The commands of the module libpalp_tool_commands (info, phantom, palpate, bench, serve,
/// bridge-sim, sweep, errormap, study), added to @p root and @p out by its entry point of this
/// name and type; the executable holds convert and convert-tree itself.
inline constexpr const char* kCommandsEntry = "palp_tool_add_commands";
using AddCommandsFn = void (*)(CLI::App& root, std::vector<Command>& out);

/// The folder of libpalp_tool.so as loaded (the build tree's tools/ or the installed library
/// folder), where the commands module lies; empty when the loader cannot say.
std::filesystem::path toolLibraryDir();

Command addConvert(CLI::App& root);
/// `palp convert-tree` (and `palp convert-tree merge`): a folder of scans converted in one
/// process, with a manifest, --resume and --shard (convert/cmd_convert_tree.cpp).
Command addConvertTree(CLI::App& root);
Command addInfo(CLI::App& root);
Command addPhantom(CLI::App& root);
Command addBench(CLI::App& root);
/// `palp bench servo`, registered by addBench() on its `bench` node.
Command addBenchServo(CLI::App& bench);
/// `palp bench tick`, registered by addBench() on its `bench` node.
Command addBenchTick(CLI::App& bench);
Command addPalpate(CLI::App& root);
/// `palp serve`: a session for a remote device over UDP (cmd_serve.cpp).
Command addServe(CLI::App& root);
/// `palp bridge-sim`: a simulated remote device for `palp serve`.
Command addBridgeSim(CLI::App& root);
/// `palp sweep` (and `palp sweep merge`): the error-analysis sweep (cmd_sweep.cpp).
Command addSweep(CLI::App& root);
/// `palp errormap`: partial rank correlations and plots of a sweep table (cmd_errormap.cpp).
Command addErrormap(CLI::App& root);
/// `palp study`: a 2IFC stiffness study, simulated or with a person (study/cmd_study.cpp).
Command addStudy(CLI::App& root);

/// Unit axis from "+y", "-x", "y", ...; @throw palp::ValueError naming @p option and the text.
Eigen::Vector3d parseAxis(const std::string& text, const char* option);
/// Index (0 x, 1 y, 2 z) of the largest component of @p a in magnitude.
int axisIndex(const Eigen::Vector3d& a);

/// Global flags shared by subcommands.
struct Globals {
    bool quiet = false;
};
Globals& globals();

}  // namespace palp::tool
