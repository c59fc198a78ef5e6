// The palp command: convert, inspect and generate volumes, benchmark ray bundles.
#include <CLI/CLI.hpp>
#include <cstdio>
#include <exception>
#include <new>
#include <vector>

#include "commands.h"
#include "option_checks.h"
#include "palp/base/error.h"
#include "progress.h"

namespace palp::tool {
Globals& globals() {
    static Globals g;
    return g;
}
}  // namespace palp::tool

int main(int argc, char** argv) {
    CLI::App app{"palp: haptic volume palpation - convert scans, inspect volumes, make phantoms"};
    app.require_subcommand(1);
    app.set_version_flag("--version", "palp 0.1.0");
    app.add_flag("-q,--quiet", palp::tool::globals().quiet, "No progress output");
    std::vector<palp::tool::Command> commands{
        palp::tool::addConvert(app),  palp::tool::addConvertTree(app), palp::tool::addInfo(app),
        palp::tool::addPhantom(app),  palp::tool::addBench(app),       palp::tool::addPalpate(app),
        palp::tool::addServe(app),    palp::tool::addBridgeSim(app),   palp::tool::addSweep(app),
        palp::tool::addErrormap(app), palp::tool::addStudy(app)};
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
