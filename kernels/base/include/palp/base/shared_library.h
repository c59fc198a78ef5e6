#pragma once
/// @file
/// Opening palp's own shared libraries at run time (dlopen): the DICOM library beside
/// palp_volume, the palp tool's commands module beside libpalp_tool.

#include <filesystem>
#include <string>

namespace palp {

/// The folder of the loaded file (shared library or executable) that holds @p anchor, the
/// address of one of its objects, as dladdr() reports it; empty when it cannot tell.
std::filesystem::path loadedFileDir(const void* anchor);

/// Opens the shared library @p path (RTLD_NOW | RTLD_LOCAL; it stays loaded for the process's
/// life) and returns the address of its symbol @p symbol.
/// @throw palp::IoError "<path>: expected <what>, found it cannot be loaded (<dlopen's
/// reason>)", or "<path>: expected <what> with <symbol>, found no such symbol".
void* openLibrarySymbol(const std::filesystem::path& path, const char* symbol,
                        const std::string& what);

}  // namespace palp
