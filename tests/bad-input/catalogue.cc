// formloop_bad_input_catalogue BINARY [CASE...]: runs the bad-input suite (cases.h) against any formloop
// binary (an older build included) and prints each case's outcome and the catalogue counts of issue 17:
// tried / clear / vague / crash / silent / partial. Exit 0 when every case is clear.

#include <iostream>
#include <map>
#include <set>

#include "cases.h"
#include "harness.h"

int main(int argc, char** argv) {
  using namespace formloop::bad_input;
  if (argc < 2) {
    std::cerr << "usage: formloop_bad_input_catalogue BINARY [CASE...]\n";
    return 2;
  }
  const std::string binary = fs::absolute(argv[1]).string();
  std::set<std::string> only(argv + 2, argv + argc);
  std::string error;
  const fs::path fixtures = EnsureFixtures(binary, FixtureRoot(), &error);
  if (fixtures.empty()) {
    std::cerr << error << "\n";
    return 1;
  }
  const fs::path work = fs::temp_directory_path() / ("formloop-catalogue-" + std::to_string(::getpid()));
  std::map<Outcome, int> counts;
  int tried = 0;
  for (const Case& c : AllCases()) {
    if (!only.empty() && !only.count(c.name)) continue;
    const Result r = RunCase(c, binary, fixtures, work, fs::path(FORMLOOP_SOURCE_DIR) / "data");
    ++tried;
    ++counts[r.outcome];
    std::cout << OutcomeName(r.outcome) << "\t" << c.reader << "\t" << c.name << "\texit " << r.exit_code;
    if (r.outcome != Outcome::kClear) {
      std::string first = r.err.substr(0, r.err.find('\n'));
      if (first.size() > 200) first = first.substr(0, 200) + "...";
      std::cout << "\t" << first;
      for (const auto& m : r.missing) std::cout << " [lacks '" << m << "']";
      for (std::size_t k = 0; k < r.changes.size() && k < 3; ++k) std::cout << " [" << r.changes[k] << "]";
    }
    std::cout << "\n" << std::flush;
  }
  std::error_code ec;
  fs::remove_all(work, ec);
  std::cout << "tried " << tried << " / clear " << counts[Outcome::kClear] << " / vague " << counts[Outcome::kVague]
            << " / crash " << counts[Outcome::kCrash] << " / silent " << counts[Outcome::kSilent] << " / partial "
            << counts[Outcome::kPartial] << "\n";
  return counts[Outcome::kClear] == tried ? 0 : 1;
}
