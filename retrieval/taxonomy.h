#pragma once
// Concept taxonomies of the case library and the case counts behind information content
// (spec/case-library.md §3).
//
// A Taxonomy is a rooted tree of uniquely named concept nodes. Each categorical facet of a part
// (material, tolerance class, finish class, machine/tool class, shape family) has one, shipped as a
// text file under data/taxonomies/; the geometric facet's tree is the GHSOM hierarchy, built here
// from the cases' concept chains (Taxonomy::FromChains).
//
// Text format (data/taxonomies/README.md has the full description and an example):
//   # a comment; blank lines are ignored; '#' starts a comment anywhere on a line
//   material                          <- the root: the one line at indent 0, first non-comment line
//     metal                           <- two spaces per level; a child is exactly one level deeper
//       tool steel | aka=H13 steel    <- optional attributes after '|': key=value, separated by ';'
//         H13 | aka=1.2344, X40CrMoV5-1
//         P20 | aka=1.2311
//   Names are trimmed; they may contain spaces and any character except '|' and '#'. Names are
//   case-sensitive and unique in the tree. The attribute "aka" lists comma-separated aliases that
//   Find() resolves to the node (unique across names and aliases too). Other attributes are kept as
//   text for the facet's own use, e.g. the band bounds "max_mm=0.005" read by ClassifyByBand().
//   Errors name the file and line: a tab in the indent, an indent not a multiple of two, a jump of
//   more than one level, a second line at indent 0, a duplicate name or alias, an empty name, a
//   malformed attribute, a file with no node.
//
// Information content. ConceptCounts counts, for each node c, the library cases whose concept lies
// under c (c itself or a descendant; a case concept may be a leaf or an inner node):
//   count(c) = #{cases j : c is an ancestor-or-self of concept_j},   N = number of cases,
//   IC(c)    = −log(count(c) / N)   (natural log, nats),  so IC(root) = 0 and a leaf holding one case
//   of N has IC = log N, exactly as NLTK's information_content() with counts propagated to hypernyms
//   (Resnik 1995, "Using information content to evaluate semantic similarity in a taxonomy", IJCAI).
// Zero counts. IC of a node no case lies under is −log 0 = ∞ (NLTK returns 1e300 there). That is the
// everyday case of a query whose material or leaf unit is new to the library, and an infinite IC
// would make every Lin similarity with it 0 — however close the case. The policy is a choice:
//   ZeroCountPolicy::kHalfCount (default): count(c) = 0 is read as 1/2, IC(c) = log(2N): rarer than
//     any concept seen in the library (count ≥ 1) and still finite, so IC stays monotone along every
//     path (children never have a lower IC than their parent) and Lin stays in [0, 1). This is the
//     Jeffreys-style half count, applied only to zero counts; all observed counts are used as they
//     are, so results on seen concepts equal NLTK's.
//   ZeroCountPolicy::kRefuse: IC of a zero-count node is an error (BadInput naming the node).

#include <filesystem>
#include <map>
#include <optional>
#include <string>
#include <vector>

#include "core/status.h"

namespace formloop::retrieval {

class Taxonomy {
 public:
  static constexpr int kRoot = 0;   // node id of the root
  static constexpr int kNone = -1;  // parent of the root

  // A tree holding only its root.
  explicit Taxonomy(std::string root_name = "root");

  // Parses the text format above. `source` names the input in error messages (a path, or a label
  // such as "<material taxonomy>").
  static Result<Taxonomy> Parse(const std::string& text, const std::string& source);
  // Reads and parses a file; NotFound when it cannot be opened.
  static Result<Taxonomy> Load(const std::filesystem::path& path);
  // The geometric facet's tree: each chain is a path root → ... → leaf of node ids (e.g. the GHSOM
  // "root" → map units → leaf unit). All chains must start at the same root; a node that appears in
  // two chains must have the same parent in both. BadInput naming the chain index otherwise.
  static Result<Taxonomy> FromChains(const std::vector<std::vector<std::string>>& chains);

  // Adds `name` as the last child of `parent`; returns the new node id. BadInput when the name is
  // empty or already used (as a name or alias) or contains '|' or '#'; NotFound when the parent is
  // unknown. Aliases and attributes are optional.
  Result<int> AddNode(const std::string& name, const std::string& parent, const std::vector<std::string>& aliases = {},
                      const std::map<std::string, std::string>& attributes = {});

  int size() const { return static_cast<int>(nodes_.size()); }
  const std::string& name(int id) const { return nodes_.at(id).name; }
  const std::string& root_name() const { return nodes_.front().name; }
  int parent(int id) const { return nodes_.at(id).parent; }
  const std::vector<int>& children(int id) const { return nodes_.at(id).children; }
  const std::vector<std::string>& aliases(int id) const { return nodes_.at(id).aliases; }
  const std::map<std::string, std::string>& attributes(int id) const { return nodes_.at(id).attributes; }
  // Number of edges from the root (root 0).
  int depth(int id) const;
  bool IsLeaf(int id) const { return nodes_.at(id).children.empty(); }

  // Node id for a name or alias; nullopt when unknown.
  std::optional<int> Find(const std::string& name_or_alias) const;
  // The name of the node whose name or alias matches `text` but for case and surrounding blanks ("h13 " ->
  // "H13"), for a "did you mean" in messages; nullopt when none does.
  std::optional<std::string> Suggest(const std::string& text) const;
  // As Find, but NotFound naming `what` (e.g. "material") and listing a few valid names.
  Result<int> Require(const std::string& name_or_alias, const std::string& what) const;

  // [id, parent(id), ..., root]: the node and its ancestors, nearest first.
  std::vector<int> Ancestors(int id) const;
  // True when `ancestor` is `id` or one of its ancestors.
  bool IsUnder(int id, int ancestor) const;
  // Lowest common node (lowest common ancestor-or-self) of a and b.
  int Lca(int a, int b) const;
  // The leaves of the subtree rooted at id (id itself when it is a leaf), in depth-first order.
  std::vector<int> LeavesUnder(int id) const;

  // Text in the Parse format; Parse(ToText()) gives back the same tree.
  std::string ToText() const;

 private:
  struct Node {
    std::string name;
    int parent = kNone;
    std::vector<int> children;
    std::vector<std::string> aliases;
    std::map<std::string, std::string> attributes;
  };
  std::vector<Node> nodes_;
  std::map<std::string, int> index_;  // names and aliases → id
};

// Band classification over a taxonomy whose leaves carry an upper bound attribute `key` (e.g. the
// tolerance classes with "max_mm=0.005", "inf" for the open last band). Among the leaves under
// `under` that carry `key`, returns the one with the smallest bound ≥ value (bounds inclusive).
// BadInput naming `field` when value is NaN, negative or above every bound, or when a bound does not
// parse; NotFound when `under` is unknown or no leaf under it carries `key`.
Result<int> ClassifyByBand(const Taxonomy& taxonomy, const std::string& under, const std::string& key, double value,
                           const std::string& field);

enum class ZeroCountPolicy {
  kHalfCount,  // count 0 is read as 1/2: IC = log(2N) (default; see the header comment)
  kRefuse,     // IC of a zero-count node is BadInput
};

// IC from a count: −log(count / n_cases) with the zero-count policy. BadInput when n_cases < 1,
// count < 0 or count > n_cases, or count == 0 under kRefuse (the message names `node`).
Result<double> InformationContent(int count, int n_cases, ZeroCountPolicy policy, const std::string& node);

// Case counts per node of one taxonomy (which it holds a copy of).
class ConceptCounts {
 public:
  // case_concepts[j]: the concept (name or alias, leaf or inner node) of library case j. BadInput
  // when the list is empty; NotFound naming the index and the concept when one is not in the tree.
  static Result<ConceptCounts> Count(const Taxonomy& taxonomy, const std::vector<std::string>& case_concepts,
                                     ZeroCountPolicy policy = ZeroCountPolicy::kHalfCount);

  const Taxonomy& taxonomy() const { return taxonomy_; }
  ZeroCountPolicy policy() const { return policy_; }
  int cases() const { return n_cases_; }  // N
  int count(int id) const { return counts_.at(id); }
  // IC(id) in nats (see the header comment).
  Result<double> Ic(int id) const;
  Result<double> Ic(const std::string& name_or_alias) const;

 private:
  Taxonomy taxonomy_;
  ZeroCountPolicy policy_ = ZeroCountPolicy::kHalfCount;
  int n_cases_ = 0;
  std::vector<int> counts_;
};

}  // namespace formloop::retrieval
