// The palp command: convert scans here; inspect and generate volumes, palpate, benchmark, serve,
// sweep and study through the commands module, opened only when one of those is asked for.
#include <CLI/CLI.hpp>
#include <algorithm>
#include <cstdio>
#include <exception>
#include <filesystem>
#include <iterator>
#include <new>
#include <string>
#include <string_view>
#include <vector>

#include "commands.h"
#include "option_checks.h"
#include "palp/base/error.h"
#include "palp/base/shared_library.h"
#include "progress.h"

namespace {

namespace fs = std::filesystem;

/// Whether @p argv asks for a command of the commands module: the first word that is not an
/// option names the command; with none, --version is answered here and anything else (--help,
/// which lists every command, or a missing command, refused with that list) needs the module.
bool wantsModule(int argc, char** argv) {
    static constexpr std::string_view kHere[] = {"convert", "convert-tree"};
    bool version = false;
    for (int i = 1; i < argc; ++i) {
        const std::string_view arg = argv[i];
        if (arg.empty() || arg[0] != '-')
            return std::find(std::begin(kHere), std::end(kHere), arg) == std::end(kHere);
        if (arg == "-h" || arg == "--help") return true;
        version = version || arg == "--version";
    }
    return !version;
}

/// Opens the commands module beside libpalp_tool.so and adds its commands to @p app.
/// @throw palp::IoError naming the file when it cannot be opened or lacks its entry point.
void addModuleCommands(CLI::App& app, std::vector<palp::tool::Command>& commands) {
    void* entry = palp::openLibrarySymbol(
        palp::tool::toolLibraryDir() / PALP_TOOL_COMMANDS_FILE, palp::tool::kCommandsEntry,
        "palp's commands library (info, phantom, palpate, bench, serve, bridge-sim, sweep, "
        "errormap, study)");
    reinterpret_cast<palp::tool::AddCommandsFn>(entry)(app, commands);
}

}  // namespace

int main(int argc, char** argv) {
    CLI::App app{"palp: haptic volume palpation - convert scans, inspect volumes, make phantoms"};
    app.require_subcommand(1);
    app.set_version_flag("--version", "palp 0.1.0");
    app.add_flag("-q,--quiet", palp::tool::globals().quiet, "No progress output");
    std::vector<palp::tool::Command> commands{palp::tool::addConvert(app),
                                              palp::tool::addConvertTree(app)};
    if (wantsModule(argc, argv)) {
        try {
            addModuleCommands(app, commands);
        } catch (const palp::Error& e) {
            std::fprintf(stderr, "palp: error: %s\n", e.what());
            return 1;
        }
    }
    palp::tool::refuseEmptyValues(app);
    try {
        app.parse(argc, argv);
    } catch (const CLI::ParseError& e) {
        // --help and --version exit 0 through CLI11; every refusal of the command line is a
        // palp error like any other (exit 1), named by its option.
        if (e.get_exit_code() == 0) return app.exit(e);
        std::fprintf(stderr, "palp: error: %s\nRun with --help for more information.\n", e.what());
        return 1;
    }
    try {
        for (auto& c : commands) {
            if (c.app->parsed()) return c.run();
        }
    } catch (const palp::Error& e) {
        palp::tool::endProgress();
        std::fprintf(stderr, "palp: error: %s\n", e.what());
        return 1;
    } catch (const std::bad_alloc&) {
        palp::tool::endProgress();
        std::fprintf(stderr, "palp: error: out of memory\n");
        return 2;
    } catch (const std::exception& e) {
        // Not a palp error: a bug or a library's own exception that palp failed to translate.
        palp::tool::endProgress();
        std::fprintf(stderr, "palp: internal error: %s\n", e.what());
        return 2;
    }
    return 1;
}
