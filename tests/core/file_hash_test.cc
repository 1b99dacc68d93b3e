// SHA-256 of files and bytes (core/file_hash.h) against the FIPS 180-2 example vectors.

#include <filesystem>
#include <fstream>
#include <string>

#include <gtest/gtest.h>

#include "core/file_hash.h"
#include "tests/support/test_dir.h"

namespace formloop {
namespace {

TEST(FileHashTest, MatchesTheFipsExamples) {
  EXPECT_EQ(Sha256Hex("abc"), "ba7816bf8f01cfea414140de5dae2223b00361a396177a9cb410ff61f20015ad");
  EXPECT_EQ(Sha256Hex(""), "e3b0c44298fc1c149afbf4c8996fb92427ae41e4649b934ca495991b7852b855");
  EXPECT_EQ(Sha256Hex("abcdbcdecdefdefgefghfghighijhijkijkljklmklmnlmnomnopnopq"),
            "248d6a61d20638b8e5c026930c3e6039a33ce45964ff2167f6ecedd419db06c1");
  const std::filesystem::path dir = testing::FreshTestDir("formloop_file_hash");
  const std::string million_a(1000000, 'a');  // larger than the read buffer
  std::ofstream(dir / "a.bin", std::ios::binary) << million_a;
  const auto hash = Sha256OfFile(dir / "a.bin");
  ASSERT_TRUE(hash.ok()) << hash.status().ToString();
  EXPECT_EQ(*hash, "cdc76e5c9914fb9281a1c7e284d73e67f1809a48a497200e046d39ccc7112cd0");
  const auto missing = Sha256OfFile(dir / "absent.step");
  ASSERT_FALSE(missing.ok());
  EXPECT_EQ(missing.status().code(), StatusCode::kNotFound);
  EXPECT_NE(missing.status().message().find("absent.step"), std::string::npos);
  std::filesystem::remove_all(dir);
}

}  // namespace
}  // namespace formloop
