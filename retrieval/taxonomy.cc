#include "retrieval/taxonomy.h"

#include <algorithm>
#include <cctype>
#include <cmath>
#include <fstream>
#include <limits>
#include <sstream>
#include <string_view>

#include "core/number_text.h"

namespace formloop::retrieval {
namespace {

std::string Trim(const std::string& s) {
  const auto first = s.find_first_not_of(" \t\r");
  if (first == std::string::npos) return "";
  const auto last = s.find_last_not_of(" \t\r");
  return s.substr(first, last - first + 1);
}

std::vector<std::string> Split(const std::string& s, char sep) {
  std::vector<std::string> parts;
  std::string part;
  std::istringstream in(s);
  while (std::getline(in, part, sep)) parts.push_back(Trim(part));
  if (!s.empty() && s.back() == sep) parts.emplace_back();
  return parts;
}

bool ValidName(const std::string& name) {
  return !name.empty() && name.find('|') == std::string::npos && name.find('#') == std::string::npos &&
         name == Trim(name);
}

std::string Quoted(const std::string& s) { return "'" + s + "'"; }

}  // namespace

Taxonomy::Taxonomy(std::string root_name) {
  nodes_.push_back(Node{.name = std::move(root_name)});
  index_[nodes_.front().name] = kRoot;
}

Result<int> Taxonomy::AddNode(const std::string& name, const std::string& parent,
                              const std::vector<std::string>& aliases,
                              const std::map<std::string, std::string>& attributes) {
  if (!ValidName(name)) {
    return Status::BadInput(Where{.field = "name"}, "concept name " + Quoted(name) + " is not valid",
                            "use a non-empty name without '|' or '#' and without leading or trailing blanks");
  }
  const std::optional<int> parent_id = Find(parent);
  if (!parent_id) return Status::NotFound("taxonomy " + Quoted(root_name()) + " has no node " + Quoted(parent));
  std::vector<std::string> all = {name};
  all.insert(all.end(), aliases.begin(), aliases.end());
  for (size_t i = 0; i < all.size(); ++i) {
    if (i > 0 && !ValidName(all[i])) {
      return Status::BadInput(Where{.field = "aka"},
                              "alias " + Quoted(all[i]) + " of " + Quoted(name) + " is not valid",
                              "use non-empty aliases without '|' or '#'");
    }
    const auto it = index_.find(all[i]);
    const bool repeated =
        std::find(all.begin(), all.begin() + static_cast<long>(i), all[i]) != all.begin() + static_cast<long>(i);
    if (it != index_.end() || repeated) {
      return Status::BadInput(
          Where{.field = i == 0 ? "name" : "aka"},
          "duplicate concept name " + Quoted(all[i]) +
              (it != index_.end() ? " (already used by node " + Quoted(nodes_[it->second].name) + ")" : std::string()),
          "names and aliases must be unique in a taxonomy");
    }
  }
  const int id = size();
  nodes_.push_back(
      Node{.name = name, .parent = *parent_id, .children = {}, .aliases = aliases, .attributes = attributes});
  nodes_[*parent_id].children.push_back(id);
  for (const std::string& key : all) index_[key] = id;
  return id;
}

Result<Taxonomy> Taxonomy::Parse(const std::string& text, const std::string& source) {
  std::optional<Taxonomy> taxonomy;
  std::vector<int> stack;               // node id at each depth of the current path
  std::map<std::string, long> line_of;  // name/alias → line it was defined on
  std::istringstream in(text);
  std::string raw;
  long line_no = 0;
  auto where = [&](const std::string& field = "") { return Where{.file = source, .line = line_no, .field = field}; };
  while (std::getline(in, raw)) {
    ++line_no;
    const std::string line = raw.substr(0, raw.find('#'));
    if (Trim(line).empty()) continue;
    size_t indent = 0;
    while (indent < line.size() && (line[indent] == ' ' || line[indent] == '\t')) {
      if (line[indent] == '\t') {
        return Status::BadInput(where(), "tab in the indentation", "indent with two spaces per level");
      }
      ++indent;
    }
    if (indent % 2 != 0) {
      return Status::BadInput(where(), "indentation of " + std::to_string(indent) + " spaces is not a multiple of two",
                              "indent with two spaces per level");
    }
    const int level = static_cast<int>(indent / 2);
    const std::string body = line.substr(indent);
    const size_t bar = body.find('|');
    const std::string name = Trim(body.substr(0, bar));
    if (name.empty()) return Status::BadInput(where(), "empty concept name", "write the name before '|'");
    std::vector<std::string> aliases;
    std::map<std::string, std::string> attributes;
    if (bar != std::string::npos) {
      for (const std::string& item : Split(body.substr(bar + 1), ';')) {
        const size_t eq = item.find('=');
        const std::string key = eq == std::string::npos ? "" : Trim(item.substr(0, eq));
        const std::string value = eq == std::string::npos ? "" : Trim(item.substr(eq + 1));
        if (key.empty() || value.empty()) {
          return Status::BadInput(where("attributes"),
                                  "attribute " + Quoted(item) + " of " + Quoted(name) + " is not key=value",
                                  "write attributes as key=value separated by ';', e.g. 'max_mm=0.02'");
        }
        if (attributes.count(key)) {
          return Status::BadInput(where("attributes"), "attribute " + Quoted(key) + " given twice");
        }
        if (key == "aka") {
          for (const std::string& alias : Split(value, ',')) aliases.push_back(alias);
        } else {
          attributes[key] = value;
        }
      }
    }
    if (!taxonomy) {
      if (level != 0) {
        return Status::BadInput(where(), "the first concept " + Quoted(name) + " is indented",
                                "start the file with the root at indent 0");
      }
      if (!aliases.empty()) return Status::BadInput(where("aka"), "the root cannot have aliases");
      taxonomy.emplace(name);
      taxonomy->nodes_.front().attributes = attributes;
      stack = {kRoot};
      line_of[name] = line_no;
      continue;
    }
    if (level == 0) {
      return Status::BadInput(where(),
                              "second root " + Quoted(name) + " (the root is " + Quoted(taxonomy->root_name()) +
                                  " on line " + std::to_string(line_of[taxonomy->root_name()]) + ")",
                              "indent every concept but the root by two spaces per level");
    }
    if (level > static_cast<int>(stack.size())) {
      return Status::BadInput(
          where(),
          Quoted(name) + " is indented " + std::to_string(level) + " levels, more than one level below the line before",
          "indent a child exactly two spaces more than its parent");
    }
    std::vector<std::string> keys = {name};
    keys.insert(keys.end(), aliases.begin(), aliases.end());
    for (const std::string& key : keys) {
      const auto seen = line_of.find(key);
      if (seen != line_of.end()) {
        return Status::BadInput(
            where(),
            "duplicate concept name " + Quoted(key) + " (first defined on line " + std::to_string(seen->second) + ")",
            "names and aliases must be unique in a taxonomy");
      }
    }
    stack.resize(level);
    auto id = taxonomy->AddNode(name, taxonomy->name(stack.back()), aliases, attributes);
    if (!id.ok()) {
      return Status::BadInput(FormatWhere(where()) + id.status().message());
    }
    for (const std::string& key : keys) line_of[key] = line_no;
    stack.push_back(*id);
  }
  if (!taxonomy) {
    return Status::BadInput(Where{.file = source}, "the taxonomy is empty (no concept line)",
                            "write the root name on the first line and its children below, two spaces per level");
  }
  return std::move(*taxonomy);
}

Result<Taxonomy> Taxonomy::Load(const std::filesystem::path& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) return Status::NotFound("cannot open taxonomy file '" + path.string() + "'");
  std::ostringstream text;
  text << in.rdbuf();
  return Parse(text.str(), path.string());
}

Result<Taxonomy> Taxonomy::FromChains(const std::vector<std::vector<std::string>>& chains) {
  if (chains.empty()) return Status::BadInput(Where{.field = "chains"}, "no concept chain given");
  for (size_t i = 0; i < chains.size(); ++i) {
    if (chains[i].empty()) {
      return Status::BadInput(Where{.field = "chains[" + std::to_string(i) + "]"}, "empty concept chain",
                              "give each chain from the root to the leaf unit");
    }
  }
  Taxonomy tree(chains.front().front());
  if (!ValidName(tree.root_name())) {
    return Status::BadInput(Where{.field = "chains[0][0]"}, "root id " + Quoted(tree.root_name()) + " is not valid");
  }
  for (size_t i = 0; i < chains.size(); ++i) {
    const std::string field = "chains[" + std::to_string(i) + "]";
    if (chains[i].front() != tree.root_name()) {
      return Status::BadInput(
          Where{.field = field},
          "chain starts at " + Quoted(chains[i].front()) + ", not at the root " + Quoted(tree.root_name()),
          "start every chain at the same root");
    }
    for (size_t k = 1; k < chains[i].size(); ++k) {
      const std::string& node = chains[i][k];
      const std::string& parent = chains[i][k - 1];
      const std::optional<int> id = tree.Find(node);
      if (id) {
        if (*id == kRoot || tree.name(tree.parent(*id)) != parent) {
          return Status::BadInput(
              Where{.field = field},
              "node " + Quoted(node) + " follows " + Quoted(parent) + " here but " +
                  (*id == kRoot ? std::string("is the root") : Quoted(tree.name(tree.parent(*id)))) +
                  " in an earlier chain",
              "a node id must have one parent in every chain");
        }
        continue;
      }
      auto added = tree.AddNode(node, parent);
      if (!added.ok()) return added.status().WithContext(field);
    }
  }
  return tree;
}

int Taxonomy::depth(int id) const {
  int d = 0;
  for (int n = nodes_.at(id).parent; n != kNone; n = nodes_[n].parent) ++d;
  return d;
}

std::optional<std::string> Taxonomy::Suggest(const std::string& text) const {
  auto folded = [](std::string_view t) {
    const auto begin = t.find_first_not_of(" \t\r\n");
    const auto end = t.find_last_not_of(" \t\r\n");
    std::string out(begin == std::string_view::npos ? std::string_view() : t.substr(begin, end - begin + 1));
    for (char& c : out) c = static_cast<char>(std::tolower(static_cast<unsigned char>(c)));
    return out;
  };
  const std::string want = folded(text);
  if (want.empty()) return std::nullopt;
  for (const auto& [key, id] : index_) {
    if (folded(key) == want) return nodes_.at(static_cast<std::size_t>(id)).name;
  }
  return std::nullopt;
}

std::optional<int> Taxonomy::Find(const std::string& name_or_alias) const {
  const auto it = index_.find(name_or_alias);
  if (it == index_.end()) return std::nullopt;
  return it->second;
}

Result<int> Taxonomy::Require(const std::string& name_or_alias, const std::string& what) const {
  if (const auto id = Find(name_or_alias)) return *id;
  std::string some;
  int shown = 0;
  for (int leaf : LeavesUnder(kRoot)) {
    if (shown == 12) {
      some += ", ...";
      break;
    }
    some += (shown++ ? ", " : "") + nodes_[leaf].name;
  }
  return Status::NotFound(what + " " + Quoted(name_or_alias) + " is not a concept of the taxonomy " +
                          Quoted(root_name()) + ". Valid leaves: " + some);
}

std::vector<int> Taxonomy::Ancestors(int id) const {
  std::vector<int> chain;
  for (int n = id; n != kNone; n = nodes_.at(n).parent) chain.push_back(n);
  return chain;
}

bool Taxonomy::IsUnder(int id, int ancestor) const {
  for (int n = id; n != kNone; n = nodes_.at(n).parent) {
    if (n == ancestor) return true;
  }
  return false;
}

int Taxonomy::Lca(int a, int b) const {
  int da = depth(a), db = depth(b);
  while (da > db) a = nodes_[a].parent, --da;
  while (db > da) b = nodes_[b].parent, --db;
  while (a != b) a = nodes_[a].parent, b = nodes_[b].parent;
  return a;
}

std::vector<int> Taxonomy::LeavesUnder(int id) const {
  std::vector<int> leaves;
  std::vector<int> stack = {id};
  while (!stack.empty()) {
    const int n = stack.back();
    stack.pop_back();
    const auto& kids = nodes_.at(n).children;
    if (kids.empty()) leaves.push_back(n);
    for (auto it = kids.rbegin(); it != kids.rend(); ++it) stack.push_back(*it);
  }
  return leaves;
}

std::string Taxonomy::ToText() const {
  std::string out;
  std::vector<int> stack = {kRoot};
  while (!stack.empty()) {
    const int n = stack.back();
    stack.pop_back();
    const Node& node = nodes_[n];
    out += std::string(2 * depth(n), ' ') + node.name;
    std::vector<std::string> items;
    if (!node.aliases.empty()) {
      std::string aka = "aka=";
      for (size_t i = 0; i < node.aliases.size(); ++i) aka += (i ? ", " : "") + node.aliases[i];
      items.push_back(aka);
    }
    for (const auto& [key, value] : node.attributes) items.push_back(key + "=" + value);
    for (size_t i = 0; i < items.size(); ++i) out += (i ? "; " : " | ") + items[i];
    out += "\n";
    for (auto it = node.children.rbegin(); it != node.children.rend(); ++it) stack.push_back(*it);
  }
  return out;
}

Result<int> ClassifyByBand(const Taxonomy& taxonomy, const std::string& under, const std::string& key, double value,
                           const std::string& field) {
  if (!std::isfinite(value) || value < 0) {
    return Status::BadInput(Where{.field = field}, "value " + FormatExact(value) + " is not a finite number ≥ 0",
                            "give a finite, non-negative value");
  }
  FL_ASSIGN_OR_RETURN(const int top, taxonomy.Require(under, field + " class"));
  int best = Taxonomy::kNone;
  double best_bound = std::numeric_limits<double>::infinity();
  double largest = -1;
  bool any = false;
  for (int leaf : taxonomy.LeavesUnder(top)) {
    const auto& attributes = taxonomy.attributes(leaf);
    const auto it = attributes.find(key);
    if (it == attributes.end()) continue;
    any = true;
    double bound = 0;
    if (!ParseDouble(it->second, &bound) || std::isnan(bound) || bound < 0) {
      return Status::BadInput(Where{.field = key},
                              "band bound " + Quoted(it->second) + " of " + Quoted(taxonomy.name(leaf)) +
                                  " in taxonomy " + Quoted(taxonomy.root_name()) + " is not a number ≥ 0",
                              "write a decimal number or 'inf'");
    }
    largest = std::max(largest, bound);
    if (value <= bound && (best == Taxonomy::kNone || bound < best_bound)) {
      best = leaf;
      best_bound = bound;
    }
  }
  if (!any) {
    return Status::NotFound("no leaf under " + Quoted(under) + " of taxonomy " + Quoted(taxonomy.root_name()) +
                            " carries the band attribute " + Quoted(key));
  }
  if (best == Taxonomy::kNone) {
    return Status::BadInput(Where{.field = field},
                            "value " + FormatExact(value) + " is above the largest band bound " + FormatExact(largest) +
                                " (" + key + ") under " + Quoted(under),
                            "add an open band ('" + key + "=inf') to the taxonomy or check the value");
  }
  return best;
}

Result<double> InformationContent(int count, int n_cases, ZeroCountPolicy policy, const std::string& node) {
  if (n_cases < 1 || count < 0 || count > n_cases) {
    return Status::BadInput(Where{.field = node}, "count " + std::to_string(count) + " of " + std::to_string(n_cases) +
                                                      " cases is not a frequency");
  }
  if (count == 0) {
    if (policy == ZeroCountPolicy::kRefuse) {
      return Status::BadInput(
          Where{.field = node},
          "no library case lies under concept " + Quoted(node) + ", so its information content is undefined",
          "use ZeroCountPolicy::kHalfCount or add a case with this concept");
    }
    return std::log(2.0 * n_cases);  // −log(0.5 / N)
  }
  // −log(count/N) written as log(N/count): exactly 0 for the root.
  return std::log(static_cast<double>(n_cases) / static_cast<double>(count));
}

Result<ConceptCounts> ConceptCounts::Count(const Taxonomy& taxonomy, const std::vector<std::string>& case_concepts,
                                           ZeroCountPolicy policy) {
  if (case_concepts.empty()) {
    return Status::BadInput(Where{.field = "case_concepts"},
                            "no cases: information content needs at least one case in the library");
  }
  ConceptCounts counts;
  counts.taxonomy_ = taxonomy;
  counts.policy_ = policy;
  counts.n_cases_ = static_cast<int>(case_concepts.size());
  counts.counts_.assign(taxonomy.size(), 0);
  for (size_t j = 0; j < case_concepts.size(); ++j) {
    const auto id = taxonomy.Find(case_concepts[j]);
    if (!id) {
      auto missing = taxonomy.Require(case_concepts[j], "case concept");
      return Status::NotFound("case " + std::to_string(j) + ": " + missing.status().message());
    }
    for (int n : taxonomy.Ancestors(*id)) ++counts.counts_[n];
  }
  return counts;
}

Result<double> ConceptCounts::Ic(int id) const {
  if (id < 0 || id >= taxonomy_.size()) {
    return Status::Internal("node id " + std::to_string(id) + " is outside the taxonomy");
  }
  return InformationContent(counts_[id], n_cases_, policy_, taxonomy_.name(id));
}

Result<double> ConceptCounts::Ic(const std::string& name_or_alias) const {
  FL_ASSIGN_OR_RETURN(const int id, taxonomy_.Require(name_or_alias, "concept"));
  return Ic(id);
}

}  // namespace formloop::retrieval
