#pragma once
// SHA-256 of a file (FIPS 180-4), through OpenSSL's EVP interface: the run folder records the hash of
// every input file it copies (a CAD model, a scan), so a run repeated from its folder can tell that it
// reads the same bytes.

#include <filesystem>
#include <string>

#include "core/status.h"

namespace formloop {

// Lower-case hexadecimal, 64 characters. NotFound / IoError naming the file.
Result<std::string> Sha256OfFile(const std::filesystem::path& path);
// The same of bytes in memory.
std::string Sha256Hex(const std::string& bytes);

}  // namespace formloop
