#pragma once
// The bad-input catalogue of issue 17, as cases: every reader (point files, STEP/IGES, part/model/profile/
// case JSON, probe logs, plans, G-code, tool-path and side files, fields, libraries, paths) and every
// command's options, each with the exit code it must give and what its message must name. Each case runs
// in its own folder; the harness (harness.h) also checks that nothing was written or deleted.

#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "harness.h"

namespace formloop::bad_input {

// Case builder: C("name", "reader", "args", exit code, {mentions}).File(...).Copy(...)
struct C {
  Case c;
  C(std::string name, std::string reader, std::string args, int exit_code, std::vector<std::string> mentions) {
    c.name = std::move(name);
    c.reader = std::move(reader);
    c.args = std::move(args);
    c.exit_code = exit_code;
    c.mentions = std::move(mentions);
  }
  C& File(std::string name, Content content) {
    c.files.emplace_back(std::move(name), std::move(content));
    return *this;
  }
  C& File(std::string name, std::string text) { return File(std::move(name), Text(std::move(text))); }
  C& Copy(std::string name) {
    c.copies.push_back(std::move(name));
    return *this;
  }
  C& Setup(std::string command) {
    c.setup.push_back(std::move(command));
    return *this;
  }
  C& ThirdPartyCrash() {
    c.third_party_crash = true;
    return *this;
  }
  C& FailedFolder(std::string dir) {
    c.failed = std::move(dir);
    return *this;
  }
  C& Cwd(std::string dir) {
    c.cwd = std::move(dir);
    return *this;
  }
  operator Case() const { return c; }  // NOLINT(google-explicit-constructor)
};

// The lean part with one field replaced (JSON pointer) by a value.
inline std::string PartWith(const std::string& pointer, const nlohmann::json& value) {
  nlohmann::json part = nlohmann::json::parse(LeanPart());
  part[nlohmann::json::json_pointer(pointer)] = value;
  return part.dump(2) + "\n";
}
// An input kept in the fuzz corpus (fuzz/corpus/<target>/<file>), byte for byte.
inline Content FuzzFinding(const std::string& name) {
  return [name](const Fixtures&) { return ReadText(fs::path(FORMLOOP_SOURCE_DIR) / "fuzz/corpus" / name); };
}
inline std::string PartWithout(const std::string& key) {
  nlohmann::json part = nlohmann::json::parse(LeanPart());
  part.erase(key);
  return part.dump(2) + "\n";
}

// A fixture file with its text changed: the `row`-th line (0-based) replaced, or a line appended.
inline Content LineOf(const std::string& fixture, std::size_t row, std::string line) {
  return [=](const Fixtures& f) {
    std::vector<std::string> lines = Lines(f.Read(fixture));
    if (row < lines.size()) lines[row] = line;
    return Join(lines);
  };
}
inline Content Changed(const std::string& fixture, std::string from, std::string to) {
  return [=](const Fixtures& f) { return ReplaceOnce(f.Read(fixture), from, to); };
}
inline Content Head(const std::string& fixture, std::size_t bytes) {
  return [=](const Fixtures& f) { return f.Read(fixture).substr(0, bytes); };
}
// The probe log with every centre moved along z.
inline Content LogShifted(double dz) {
  return [=](const Fixtures& f) {
    std::vector<std::string> lines = Lines(f.Read("log.csv"));
    for (auto& line : lines) {
      if (line.empty() || line[0] == '#' || line[0] == 'i') continue;
      std::vector<std::string> cells;
      std::stringstream cs(line);
      std::string cell;
      while (std::getline(cs, cell, ',')) cells.push_back(cell);
      cells[3] = std::to_string(std::stod(cells[3]) + dz);
      line.clear();
      for (std::size_t k = 0; k < cells.size(); ++k) line += (k ? "," : "") + cells[k];
    }
    return Join(lines);
  };
}

inline const std::string kProject = "project --surface {F}/Q.step --points ";
inline const std::string kAnalyse = "analyse --surface {F}/Q.step --out an --probe-log ";
inline const std::string kCompensate = "nc compensate --toolpath tp.csv --field field.csv ";
inline const std::string kCheck = "nc check --nominal n.ngc --compensated c.ngc --side s.csv";

inline std::vector<Case> AllCases() {
  std::vector<Case> cases = {
      // ---- output folders: only formloop's, never the current directory or an input (item 1)
      C("run_out_parent_of_cwd", "output folder", "run {F}/part.json --out .. --force", 2,
        {"current directory", "--out"})
          .Setup("mkdir -p x/inner && echo keep > x/keep.txt")
          .Cwd("x/inner"),
      C("run_force_user_folder", "output folder", "run {F}/part.json --out mine --force", 2,
        {"mine", ".formloop-output"})
          .Setup("mkdir mine && echo keep > mine/keep.txt"),
      C("run_out_is_cwd", "output folder", "run {F}/part.json --out . --force", 2, {"current directory"})
          .Setup("echo keep > keep.txt"),
      C("run_out_holds_part", "output folder", "run in/part.json --out in --force", 2, {"holds the input", "part.json"})
          .File("in/part.json", LeanPart())
          .File("in/.formloop-output", "{}\n"),
      C("run_out_exists_without_force", "output folder", "run {F}/part.json --out run", 2, {"run", "--force"})
          .Copy("run"),
      C("run_out_is_a_file", "output folder", "run {F}/part.json --out out.txt --force", 2, {"out.txt"})
          .File("out.txt", "keep\n"),
      C("run_partial_of_user", "output folder", "run {F}/part.json --out r", 2, {"r.partial"})
          .Setup("mkdir r.partial && echo keep > r.partial/notes.txt"),
      C("run_failed_of_user", "output folder", "run {F}/part.json --out r", 2, {"r.failed"})
          .Setup("mkdir r.failed && echo keep > r.failed/notes.txt"),
      C("run_batch_into_user_folder", "output folder", "run parts --out b", 2, {"b: field '--out'", ".formloop-output"})
          .File("parts/a.json", PartWith("/name", "lean-a"))
          .File("parts/b.json", PartWith("/name", "lean-b"))
          .Setup("mkdir b && echo keep > b/keep.txt"),
      C("run_out_is_library", "output folder", "run {F}/part.json --kb kb.sqlite --out kb.sqlite --force", 2,
        {"kb.sqlite"})
          .Copy("kb.sqlite"),
      C("run_out_holds_measured_log", "output folder", "run {F}/part.json --measured run/mylog.csv --out run --force",
        2, {"mylog.csv"})
          .Copy("run")
          .Setup("cp run/loop-0/probe_log.csv run/mylog.csv"),
      C("diagnose_out_user_folder", "output folder", "diagnose --measured {F}/log.csv --run {F}/run --out d", 2,
        {"'d'", ".formloop-output"})
          .Setup("mkdir d && echo keep > d/keep.txt"),
      C("diagnose_out_is_run", "output folder", "diagnose --measured {F}/log.csv --run run --out run", 2, {"--run"})
          .Copy("run"),
      C("diagnose_out_holds_log", "output folder", "diagnose --measured dd/log.csv --run {F}/run --out dd", 2,
        {"log.csv"})
          .File("dd/log.csv", [](const Fixtures& f) { return f.Read("log.csv"); })
          .File("dd/.formloop-output", "{}\n"),
      C("diagnose_out_is_cwd", "output folder", "diagnose --measured {F}/log.csv --run {F}/run --out .", 2,
        {"current directory"})
          .Setup("echo keep > keep.txt"),
      C("regress_out_user_folder", "output folder",
        "regress --parts {DATA}/regress/parts --goldens g --only reg-dome-a --out reg", 2,
        {"'reg'", ".formloop-output"})
          .Setup("mkdir reg && echo keep > reg/keep.txt"),
      C("regress_out_is_cwd", "output folder",
        "regress --parts {DATA}/regress/parts --goldens {D}/g --only reg-dome-a --out .", 2, {"current directory"})
          .Setup("mkdir sub && echo keep > sub/keep.txt")
          .Cwd("sub"),
      C("analyse_out_user_folder", "output folder", kAnalyse + "{F}/log.csv", 2, {"'an'", ".formloop-output"})
          .Setup("mkdir an && echo keep > an/keep.txt"),
      C("analyse_out_holds_log", "output folder", "analyse --surface {F}/Q.step --probe-log an/log.csv --out an", 2,
        {"log.csv"})
          .File("an/log.csv", [](const Fixtures& f) { return f.Read("log.csv"); }),

      // ---- an output file that exists: refused without --force, and with it unless formloop wrote it
      C("nc_path_out_exists", "output file", "nc path --surface {F}/Q.step --out notes.txt", 2,
        {"notes.txt: field '--out': already exists", "--force"})
          .File("notes.txt", "my notes\n"),
      C("nc_path_force_user_file", "output file", "nc path --surface {F}/Q.step --out notes.txt --force", 2,
        {"notes.txt", "formloop did not write it"})
          .File("notes.txt", "my notes\n"),
      C("nc_path_toolpath_force_user_file", "output file", "nc path --surface {F}/Q.step --toolpath notes.txt --force",
        2, {"notes.txt", "--toolpath", "did not write"})
          .File("notes.txt", "x,y,z\n1,2,3\n"),
      C("nc_probe_force_user_part", "output file", "nc probe --surface {F}/Q.step --out p.json --force", 2,
        {"p.json", "did not write"})
          .File("p.json", LeanPart()),
      C("fit_force_user_step", "output file", "fit analytic:saddle --out user.step --force", 2,
        {"user.step", "did not write"})
          .File("user.step", "ISO-10303-21;\nHEADER;\nFILE_NAME('u','t',(''),(''),'','OtherCAD','');\nENDSEC;\n"),
      C("report_force_user_html", "output file", "report run --out mine.html --force", 2,
        {"mine.html", "did not write"})
          .Copy("run")
          .File("mine.html", "<!DOCTYPE html>\n<html><head><title>mine</title></head></html>\n"),
      C("project_out_exists", "output file", kProject + "scan.csv --out user.csv", 2, {"user.csv", "already exists"})
          .Copy("scan.csv")
          .File("user.csv", "a,b\n1,2\n"),
      C("calibrate_force_user_json", "output file",
        "calibrate sphere sphere.csv --radius 12.5 --ball 1 --out p3.json --force", 2, {"p3.json", "did not write"})
          .Copy("sphere.csv")
          .File("p3.json", "{\"format\": \"my-part\", \"generator\": \"me\"}\n"),
      C("kb_export_force_user_file", "output file", "kb export kb.sqlite --out user.jsonl --force", 2,
        {"user.jsonl", "did not write"})
          .Copy("kb.sqlite")
          .File("user.jsonl", "{\"type\": \"mine\"}\n"),
      C("surfaces_sample_out_is_folder", "output file", "surfaces sample saddle --nu 3 --nv 3 --out d.csv --force", 2,
        {"d.csv", "is a folder"})
          .Setup("mkdir d.csv"),

      // ---- an output onto an input (item 2)
      C("kb_export_onto_library", "output path", "kb export kb.sqlite --out kb.sqlite", 2, {"kb.sqlite", "--out"})
          .Copy("kb.sqlite"),
      C("kb_export_onto_hard_link", "output path", "kb export kb.sqlite --out same.sqlite", 2,
        {"same.sqlite", "kb.sqlite"})
          .Copy("kb.sqlite")
          .Setup("ln kb.sqlite same.sqlite"),
      C("kb_export_onto_symlink", "output path", "kb export kb.sqlite --out link.jsonl", 2, {"link.jsonl"})
          .Copy("kb.sqlite")
          .Setup("ln -s kb.sqlite link.jsonl"),
      C("nc_compensate_out_is_side", "output path", kCompensate + "--out X.ngc --side X.ngc", 2, {"X.ngc", "--side"})
          .Copy("tp.csv")
          .Copy("field.csv"),
      C("nc_compensate_out_is_toolpath", "output path", kCompensate + "--out tp.csv --side s.csv", 2,
        {"tp.csv", "--toolpath"})
          .Copy("tp.csv")
          .Copy("field.csv"),
      C("nc_compensate_side_is_field", "output path", kCompensate + "--out p.ngc --side field.csv", 2,
        {"field.csv", "--field"})
          .Copy("tp.csv")
          .Copy("field.csv"),
      C("nc_compensate_out_is_nominal", "output path", kCompensate + "--nominal prog.ngc --out prog.ngc --side s.csv",
        2, {"prog.ngc", "--nominal"})
          .Copy("tp.csv")
          .Copy("field.csv")
          .Copy("prog.ngc"),
      C("report_out_is_summary", "output path", "report run --out run/summary.json", 2, {"summary.json"}).Copy("run"),
      C("nc_post_out_is_toolpath", "output path", "nc post --toolpath tp.csv --out tp.csv", 2, {"tp.csv", "--out"})
          .Copy("tp.csv"),
      C("nc_post_out_is_toolpath_dotted", "output path", "nc post --toolpath tp.csv --out ./tp.csv", 2, {"tp.csv"})
          .Copy("tp.csv"),
      C("project_out_is_points", "output path", kProject + "scan.csv --out scan.csv", 2, {"scan.csv", "--points"})
          .Copy("scan.csv"),
      C("moran_lisa_is_points", "output path", "analyse moran --points t.csv --value v --knn 2 --style W --lisa t.csv",
        2, {"t.csv", "--lisa"})
          .File("t.csv", "x,y,v\n0,0,1\n1,0,2\n0,1,3\n1,1,4\n2,2,5\n"),
      C("fit_out_is_input", "output path", "fit Q.step --out Q.step", 2, {"Q.step", "INPUT"}).Copy("Q.step"),
      C("simulate_out_is_model", "output path", "simulate --run {F}/run --model m.json --out m.json", 2,
        {"m.json", "--model"})
          .File("m.json", [](const Fixtures& f) { return f.Read("model.json"); }),
      C("simulate_out_is_truth", "output path",
        "simulate --run {F}/run --model {F}/model.json --out a.csv --truth a.csv", 2, {"a.csv", "--truth"}),
      C("simulate_out_in_run_folder", "output path",
        "simulate --run run --model {F}/model.json --out run/toolpath/toolpath.csv", 2, {"toolpath.csv"})
          .Copy("run"),
      C("calibrate_out_is_log", "output path", "calibrate sphere sphere.csv --radius 12.5 --ball 1 --out sphere.csv", 2,
        {"sphere.csv", "--out"})
          .Copy("sphere.csv"),
      C("nc_path_out_is_surface", "output path", "nc path --surface Q.step --out Q.step", 2, {"Q.step", "--surface"})
          .Copy("Q.step"),
      C("nc_path_out_is_toolpath", "output path", "nc path --surface {F}/Q.step --out a.ngc --toolpath a.ngc", 2,
        {"a.ngc", "--toolpath"}),
      C("nc_probe_out_is_surface", "output path", "nc probe --surface Q.step --out Q.step", 2, {"Q.step"})
          .Copy("Q.step"),
      C("surfaces_export_report_not_json", "output path", "surfaces export saddle --out a.step --report a.step", 2,
        {"--report"}),

      // ---- point files: CSV, XYZ, PLY, PCD
      C("csv_missing_column_z", "point file", "fit p.csv --out q.step", 2, {"p.csv:1", "z"})
          .File("p.csv", "x,y\n1,2\n"),
      C("csv_not_a_number", "point file", "fit p.csv --out q.step", 2, {"p.csv:3", "field 'y'"})
          .File("p.csv", "x,y,z\n1,2,3\n4,abc,6\n"),
      C("csv_nan", "point file", "fit p.csv --out q.step", 2, {"p.csv:3", "field 'z'"})
          .File("p.csv", "x,y,z\n1,2,3\n4,5,nan\n"),
      C("csv_infinity", "point file", "fit p.csv --out q.step", 2, {"p.csv:2", "field 'x'"})
          .File("p.csv", "x,y,z\ninf,2,3\n"),
      C("csv_huge_coordinate", "point file", kProject + "p.csv --out o.csv", 2, {"p.csv:3", "field 'x'"})
          .File("p.csv", "x,y,z\n1,2,3\n1e300,2,3\n4,5,6\n"),
      C("csv_ragged_row", "point file", "fit p.csv --out q.step", 2, {"p.csv:3"}).File("p.csv", "x,y,z\n1,2,3\n4,5\n"),
      C("csv_empty", "point file", "fit p.csv --out q.step", 2, {"p.csv"}).File("p.csv", ""),
      C("csv_header_only", "point file", "fit p.csv --out q.step", 2, {"p.csv"}).File("p.csv", "x,y,z\n"),
      C("csv_duplicate_column", "point file", "fit p.csv --out q.step", 2, {"p.csv:1", "z"})
          .File("p.csv", "x,y,z,z\n1,2,3,4\n"),
      C("csv_utf16", "point file", "fit p.csv --out q.step", 2, {"p.csv", "UTF-16"})
          .File("p.csv", std::string("\xFF\xFEx\0,\0y\0,\0z\0\n\0", 14)),
      C("csv_binary", "point file", "fit p.csv --out q.step", 2, {"p.csv"})
          .File("p.csv", std::string("\x7f"
                                     "ELF\x02\x01\x01\0\0\0\0\0\0\0\0\0",
                                     16)),
      C("csv_decimal_comma_with_commas", "point file", "fit p.csv --out q.step", 2, {"p.csv:2", "decimal comma"})
          .File("p.csv", "x,y,z\n1,5,2,5,3,5\n"),
      C("csv_semicolon_not_a_number", "point file", "fit p.csv --out q.step", 2, {"p.csv:2", "field 'y'"})
          .File("p.csv", "x;y;z\n1,5;abc;3\n"),
      C("csv_id_not_integer", "point file", "fit p.csv --out q.step", 2, {"p.csv:2", "id"})
          .File("p.csv", "x,y,z,id\n1,2,3,1.5\n"),
      C("xyz_four_columns", "point file", "fit p.xyz --out q.step", 2, {"p.xyz:1"}).File("p.xyz", "1 2 3 4\n"),
      C("xyz_not_a_number", "point file", "fit p.xyz --out q.step", 2, {"p.xyz:2", "field 'z'"})
          .File("p.xyz", "1 2 3\n4 5 six\n"),
      C("xyz_huge_coordinate", "point file", kProject + "p.xyz --out o.csv", 2, {"p.xyz:2", "field 'z'"})
          .File("p.xyz", "1 2 3\n4 5 -1e300\n"),
      C("ply_ascii_truncated", "point file", "fit p.ply --out q.step", 2, {"p.ply"})
          .File("p.ply",
                "ply\nformat ascii 1.0\nelement vertex 10\nproperty float x\nproperty float y\nproperty float z\n"
                "end_header\n1 2 3\n4 5 6\n"),
      C("ply_binary_truncated", "point file", "fit p.ply --out q.step", 2, {"p.ply"})
          .File("p.ply",
                "ply\nformat binary_little_endian 1.0\nelement vertex 1000\nproperty float x\nproperty float y\n"
                "property float z\nend_header\nabcdefgh"),
      C("ply_huge_vertex_count", "point file", "fit p.ply --out q.step", 2, {"p.ply"})
          .File("p.ply",
                "ply\nformat binary_little_endian 1.0\nelement vertex 1000000000000\nproperty double x\n"
                "property double y\nproperty double z\nend_header\n"),
      C("ply_bad_magic", "point file", "fit p.ply --out q.step", 2, {"p.ply"})
          .File("p.ply", "plx\nformat ascii 1.0\nend_header\n"),
      C("ply_no_vertex_element", "point file", "fit p.ply --out q.step", 2, {"p.ply"})
          .File("p.ply",
                "ply\nformat ascii 1.0\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n"
                "3 0 1 2\n"),
      C("ply_ascii_huge_coordinate", "point file", kProject + "p.ply --out o.csv", 2, {"p.ply:9", "field 'y'"})
          .File("p.ply",
                "ply\nformat ascii 1.0\nelement vertex 2\nproperty float x\nproperty float y\nproperty float z\n"
                "end_header\n1 2 3\n4 1e300 6\n"),
      C("pcd_bad_header", "point file", "fit p.pcd --out q.step", 2, {"p.pcd"})
          .File("p.pcd", "# .PCD v0.7\nVERSION 0.7\nFIELDS x y\nSIZE 4 4 4\n"),
      C("pcd_huge_point_count", "point file", "fit p.pcd --out q.step", 2, {"p.pcd"})
          .File("p.pcd",
                "# .PCD v0.7\nVERSION 0.7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\nWIDTH 1000000000000\n"
                "HEIGHT 1\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS 1000000000000\nDATA binary\n"),
      C("pcd_binary_truncated", "point file", "fit p.pcd --out q.step", 2, {"p.pcd"})
          .File("p.pcd",
                "# .PCD v0.7\nVERSION 0.7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\nWIDTH 100\nHEIGHT 1\n"
                "VIEWPOINT 0 0 0 1 0 0 0\nPOINTS 100\nDATA binary\nabcdefgh"),
      C("pcd_ascii_huge_coordinate", "point file", kProject + "p.pcd --out o.csv", 2, {"p.pcd", "'x'"})
          .File("p.pcd",
                "# .PCD v0.7\nVERSION 0.7\nFIELDS x y z\nSIZE 8 8 8\nTYPE F F F\nCOUNT 1 1 1\nWIDTH 2\nHEIGHT 1\n"
                "VIEWPOINT 0 0 0 1 0 0 0\nPOINTS 2\nDATA ascii\n1 2 3\n1e300 2 3\n"),
      C("points_unknown_extension", "point file", "fit p.dat --out q.step", 2, {"p.dat"}).File("p.dat", "1 2 3\n"),
      C("points_missing_file", "point file", kProject + "missing.csv --out o.csv", 2, {"missing.csv"}),
      C("points_is_a_folder", "point file", kProject + "d.csv --out o.csv", 2, {"d.csv"}).Setup("mkdir d.csv"),
      C("moran_table_missing_value", "CSV table", "analyse moran --points t.csv --value w --knn 2 --style W", 2,
        {"t.csv", "--value", "'w'"})
          .File("t.csv", "x,y,v\n0,0,1\n1,0,2\n0,1,3\n1,1,5\n2,2,4\n"),
      C("moran_table_ragged", "CSV table", "analyse moran --points t.csv --value v --knn 2 --style W", 2, {"t.csv:3"})
          .File("t.csv", "x,y,v\n0,0,1\n1,0\n0,1,3\n"),
      C("moran_table_bad_number", "CSV table", "analyse moran --points t.csv --value v --knn 2 --style W", 2,
        {"t.csv:4", "'v'"})
          .File("t.csv", "x,y,v\n0,0,1\n1,0,2\n0,1,three\n"),
      C("moran_gal_garbage", "GAL weights", "analyse moran --points t.csv --value v --weights w.gal --style W", 2,
        {"w.gal"})
          .File("t.csv", "x,y,v\n0,0,1\n1,0,2\n0,1,3\n1,1,5\n2,2,4\n")
          .File("w.gal", "three\n1 two\n"),

      // ---- CAD files: STEP and IGES
      C("step_empty", "STEP/IGES", "fit e.step --out q.step", 2, {"e.step"}).File("e.step", ""),
      C("step_garbage", "STEP/IGES", "fit g.step --out q.step", 2, {"g.step"}).File("g.step", "hello, world\n"),
      C("step_truncated", "STEP/IGES", "fit t.step --out q.step", 2, {"t.step"}).File("t.step", Head("Q.step", 3000)),
      C("step_without_faces", "STEP/IGES", "fit n.step --out q.step", 2, {"n.step"})
          .File("n.step",
                "ISO-10303-21;\nHEADER;\nFILE_DESCRIPTION(('x'),'2;1');\nFILE_NAME('n','2024-01-01T00:00:00',(''),"
                "(''),'','','');\nFILE_SCHEMA(('AUTOMOTIVE_DESIGN'));\nENDSEC;\nDATA;\nENDSEC;\nEND-ISO-10303-21;\n"),
      C("iges_garbage", "STEP/IGES", "fit g.igs --out q.step", 2, {"g.igs"}).File("g.igs", "not an iges file\n"),
      C("step_face_index_out_of_range", "STEP/IGES", "fit {F}/Q.step --face 5 --out q.step", 2,
        {"Q.step", "face index 5"}),
      C("step_face_index_negative", "STEP/IGES", "fit {F}/Q.step --face -2 --out q.step", 2, {"Q.step", "face index"}),
      C("step_face_name_unknown", "STEP/IGES", "fit {F}/Q.step --face-name nope --out q.step", 2, {"nope"}),
      C("step_holding_ply_text", "STEP/IGES", "fit p.step --out q.step", 2, {"p.step"})
          .File("p.step", "ply\nformat ascii 1.0\nend_header\n"),
      C("nc_path_surface_missing", "STEP/IGES", "nc path --surface missing.step --out p.ngc", 2, {"missing.step"}),
      C("analyse_surface_garbage", "STEP/IGES", "analyse --surface g.step --probe-log {F}/log.csv --out an", 2,
        {"g.step"})
          .File("g.step", "ISO-10303-21;\nDATA;\n#1=FOO(;\n"),
      // Files on which OpenCASCADE 7.6's readers crash (fuzz/corpus/fuzz_step|fuzz_iges/crash-*): the reader runs
      // in a child process, so every command that reads CAD ends with an error naming the file, not a signal.
      C("step_occt_crash_fit", "STEP/IGES", "fit c.step --out q.step", 2, {"c.step", "could not be read"})
          .File("c.step", FuzzFinding("fuzz_step/crash-occt-null-cartesian-point.step"))
          .ThirdPartyCrash(),
      C("step_occt_crash_run_part", "STEP/IGES", "run p.json --out r", 2, {"c.step", "surface.faces"})
          .File("c.step", FuzzFinding("fuzz_step/crash-occt-null-cartesian-point.step"))
          .File("p.json", PartWith("/surface", {{"cad", "c.step"}, {"faces", {0}}}))
          .ThirdPartyCrash(),
      C("step_occt_crash_nc_compensate_program", "STEP/IGES",
        "nc compensate --program {F}/prog.ngc --surface c.step --ball-radius-mm 3 --field {F}/field.csv --out o.ngc "
        "--side s.csv",
        2, {"c.step", "could not be read"})
          .File("c.step", FuzzFinding("fuzz_step/crash-occt-null-cartesian-point.step"))
          .ThirdPartyCrash(),
      C("iges_occt_crash_fit", "STEP/IGES", "fit c.igs --out q.step", 2, {"c.igs"})
          .File("c.igs", FuzzFinding("fuzz_iges/crash-occt-igesread-out-of-bounds.igs"))
          .ThirdPartyCrash(),
      C("iges_occt_crash_run_part", "STEP/IGES", "run p.json --out r", 2, {"c.igs", "surface.faces"})
          .File("c.igs", FuzzFinding("fuzz_iges/crash-occt-igesread-out-of-bounds.igs"))
          .File("p.json", PartWith("/surface", {{"cad", "c.igs"}, {"faces", {0}}}))
          .ThirdPartyCrash(),
      // A negative face index (-1 used to pass as "no face given"), "reverse" on a region of several faces.
      C("part_cad_face_negative", "part JSON", "run p.json --out r", 2, {"p.json", "surface.faces[0]"})
          .Copy("Q.step")
          .File("p.json", PartWith("/surface", {{"cad", "Q.step"}, {"faces", {-1}}})),
      C("part_cad_reverse_region", "part JSON", "run p.json --out r", 2, {"p.json", "surface.reverse"})
          .Copy("Q.step")
          .File("p.json", PartWith("/surface", {{"cad", "Q.step"}, {"faces", {0, 0}}, {"reverse", true}})),
      // The virtual machine with neither machine.effects nor a profile named by machine.name.
      C("part_machine_without_profile", "part JSON", "run p.json --out r", 2, {"p.json", "machine.name", "vm-mill-a"})
          .File("p.json",
                [] {
                  nlohmann::json part = nlohmann::json::parse(LeanPart());
                  part["machine"].erase("effects");
                  return part.dump(2) + "\n";
                }()),
      // ... and a machine.name that is a path to a profile file that is not there: that file named.
      C("part_machine_profile_path_missing", "part JSON", "run p.json --out r", 2,
        {"nowhere/mill.json", "machine profile not found"})
          .File("p.json",
                [] {
                  nlohmann::json part = nlohmann::json::parse(LeanPart());
                  part["machine"].erase("effects");
                  part["machine"]["name"] = "nowhere/mill.json";
                  return part.dump(2) + "\n";
                }()),
      // A reader past the time limit (--cad-timeout-s; 1 us expires before any reader answers) and a limit
      // that is no number of seconds.
      C("step_reader_time_limit_fit", "STEP/IGES", "--cad-timeout-s 0.000001 fit c.step --out q.step", 2,
        {"c.step", "took longer than 1e-06 s", "--cad-timeout-s"})
          .File("c.step", FuzzFinding("fuzz_step/formloop_export_saddle.step")),
      C("cad_timeout_negative", "options", "--cad-timeout-s -5 fit c.step --out q.step", 2, {"--cad-timeout-s"})
          .File("c.step", FuzzFinding("fuzz_step/formloop_export_saddle.step")),

      // ---- part JSON (formloop run PART)
      C("part_syntax_error", "part JSON", "run p.json --out r", 2, {"p.json:2", "column"})
          .File("p.json", "{ \"name\": \n"),
      C("part_number_beyond_double", "part JSON", "run p.json --out r", 2, {"p.json:2", "1e400"})
          .File("p.json", "{\"name\": \"x\",\n \"tolerance_mm\": 1e400}\n"),
      C("part_unknown_field", "part JSON", "run p.json --out r", 2, {"p.json", "tolrance_mm"})
          .File("p.json", PartWith("/tolrance_mm", 0.01)),
      C("part_tolerance_negative", "part JSON", "run p.json --out r", 2, {"p.json", "tolerance_mm"})
          .File("p.json", PartWith("/tolerance_mm", -0.01)),
      C("part_tolerance_string", "part JSON", "run p.json --out r", 2, {"p.json", "tolerance_mm"})
          .File("p.json", PartWith("/tolerance_mm", "0.01")),
      C("part_tolerance_huge", "part JSON", "run p.json --out r", 2, {"p.json", "tolerance_mm"})
          .File("p.json", PartWith("/tolerance_mm", 1000)),
      C("part_scallop_mm_typed_as_um", "part JSON", "run p.json --out r", 2, {"p.json", "scallop_um", "--yes"})
          .File("p.json", PartWith("/toolpath/scallop_um", 0.003)),
      C("part_scallop_tiny", "part JSON", "run p.json --out r", 2, {"p.json", "scallop_um"})
          .File("p.json", PartWith("/toolpath/scallop_um", 1e-9)),
      C("part_chord_tiny", "part JSON", "run p.json --out r", 2, {"p.json", "chord_tolerance_um"})
          .File("p.json", PartWith("/toolpath/chord_tolerance_um", 1e-9)),
      C("part_tool_radius_huge", "part JSON", "run p.json --out r", 2, {"p.json", "tool.radius_mm"})
          .File("p.json", PartWith("/tool/radius_mm", 1e6)),
      C("part_feed_above_machine", "part JSON", "run p.json --out r", 2, {"p.json", "feed_mm_per_min"})
          .File("p.json", PartWith("/toolpath/feed_mm_per_min", 50000)),
      C("part_spindle_above_machine", "part JSON", "run p.json --out r", 2, {"p.json", "spindle_rpm"})
          .File("p.json", PartWith("/toolpath/spindle_rpm", 90000)),
      C("part_plunge_feed_above_machine", "part JSON", "run p.json --out r", 2, {"p.json", "plunge_feed_mm_per_min"})
          .File("p.json", PartWith("/toolpath/plunge_feed_mm_per_min", 20000)),
      C("part_max_offset_huge", "part JSON", "run p.json --out r", 2, {"p.json", "max_offset_um"})
          .File("p.json", PartWith("/loops/max_offset_um", 1e9)),
      C("part_search_huge", "part JSON", "run p.json --out r", 2, {"p.json", "search_mm"})
          .File("p.json", PartWith("/probing/search_mm", 500)),
      C("part_probe_clearance_huge", "part JSON", "run p.json --out r", 2, {"p.json", "probing.clearance_mm"})
          .File("p.json", PartWith("/probing/clearance_mm", 10000)),
      C("part_probe_min_gap_zero", "part JSON", "run p.json --out r", 2, {"p.json", "probing.min_gap_mm"})
          .File("p.json", PartWith("/probing/min_gap_mm", 0)),
      C("part_probe_shank_negative", "part JSON", "run p.json --out r", 2, {"p.json", "probing.shank_radius_mm"})
          .File("p.json", PartWith("/probing/shank_radius_mm", -1)),
      C("part_probe_grid_huge", "part JSON", "run p.json --out r", 2, {"p.json", "probing.grid"})
          .File("p.json", PartWith("/probing/grid", nlohmann::json::array({1000, 1000}))),
      C("part_probe_feed_above_machine", "part JSON", "run p.json --out r", 2, {"p.json", "probing.feed_mm_per_min"})
          .File("p.json", PartWith("/probing/feed_mm_per_min", 1e6)),
      C("part_probe_ball_huge", "part JSON", "run p.json --out r", 2, {"p.json", "ball_radius_mm"})
          .File("p.json", PartWith("/probing/ball_radius_mm", 100)),
      C("part_pretravel_huge", "part JSON", "run p.json --out r", 2, {"p.json", "pretravel_mm"})
          .File("p.json", PartWith("/probing/pretravel_mm", 10)),
      C("part_probe_tool_zero", "part JSON", "run p.json --out r", 2, {"p.json", "probing.tool"})
          .File("p.json", PartWith("/probing/tool", 0)),
      C("part_sinumerik_r_last_below_base", "part JSON", "run p.json --out r", 2,
        {"p.json", "probing.sinumerik_r_last"})
          .File("p.json", PartWith("/probing/sinumerik_r_last", 5)),
      C("part_fanuc_result_base_huge", "part JSON", "run p.json --out r", 2, {"p.json", "probing.fanuc_result_base"})
          .File("p.json", PartWith("/probing/fanuc_result_base", 5000)),
      C("nc_probe_tool_zero", "options", "nc probe --surface {F}/Q.step --probe-tool 0 --out p.ngc", 2,
        {"--probe-tool"}),
      C("part_fit_samples_huge", "part JSON", "run p.json --out r", 2, {"p.json", "fit.samples_u"})
          .File("p.json", PartWith("/fit/samples_u", 5000)),
      C("part_travel_inverted", "part JSON", "run p.json --out r", 2, {"p.json", "travel"})
          .File("p.json", PartWith("/machine/travel_min_mm", nlohmann::json::array({300, -300, -150}))),
      C("part_travel_huge", "part JSON", "run p.json --out r", 2, {"p.json", "travel"})
          .File("p.json", PartWith("/machine/travel_max_mm", nlohmann::json::array({1e300, 300, 150}))),
      C("part_dialect_unknown", "part JSON", "run p.json --out r", 2, {"p.json", "machine.dialect", "haas"})
          .File("p.json", PartWith("/machine/dialect", "haas")),
      C("part_material_trailing_space", "part JSON", "run p.json --out r", 2, {"p.json", "material", "h13 "})
          .File("p.json", PartWith("/material", "h13 ")),
      C("part_surface_unknown", "part JSON", "run p.json --out r", 2, {"p.json", "surface.reference"})
          .File("p.json", PartWith("/surface/reference", "nope")),
      C("part_surface_param_negative", "part JSON", "run p.json --out r", 2, {"p.json", "surface"})
          .File("p.json", PartWith("/surface", {{"kind", "gaussian_pocket"}, {"params", {{"size_mm", -80}}}})),
      C("part_name_with_slash", "part JSON", "run p.json --out r", 2, {"p.json", "name"})
          .File("p.json", PartWith("/name", "a/b")),
      C("part_seed_negative", "part JSON", "run p.json --out r", 2, {"p.json", "seed"})
          .File("p.json", PartWith("/seed", -1)),
      C("part_tool_number_zero", "part JSON", "run p.json --out r", 2, {"p.json", "tool.number"})
          .File("p.json", PartWith("/tool/number", 0)),
      C("part_thermal_tau_zero", "part JSON", "run p.json --out r", 2, {"p.json", "thermal_tau_s"})
          .File("p.json", PartWith("/machine/effects/thermal_tau_s", 0)),
      C("part_deflection_huge", "part JSON", "run p.json --out r", 2, {"p.json", "deflection_um"})
          .File("p.json", PartWith("/machine/effects/deflection_um", 1e6)),
      C("part_lead_huge", "part JSON", "run p.json --out r", 2, {"p.json", "lead_mm"})
          .File("p.json", PartWith("/toolpath/lead_mm", 1000)),
      C("part_raster_angle_string", "part JSON", "run p.json --out r", 2, {"p.json", "raster_angle_deg"})
          .File("p.json", PartWith("/toolpath/raster_angle_deg", "abc")),
      C("part_max_spacing_zero", "part JSON", "run p.json --out r", 2, {"p.json", "max_point_spacing_mm"})
          .File("p.json", PartWith("/toolpath/max_point_spacing_mm", 0)),
      C("part_clearance_negative", "part JSON", "run p.json --out r", 2, {"p.json", "toolpath.clearance_mm"})
          .File("p.json", PartWith("/toolpath/clearance_mm", -5)),
      C("part_loops_too_many", "part JSON", "run p.json --out r", 2, {"p.json", "loops.max"})
          .File("p.json", PartWith("/loops/max", 100)),
      C("part_neighbours_zero", "part JSON", "run p.json --out r", 2, {"p.json", "neighbours"})
          .File("p.json", PartWith("/analysis/neighbours", 0)),
      C("part_empty_file", "part JSON", "run p.json --out r", 2, {"p.json"}).File("p.json", ""),
      C("part_top_level_array", "part JSON", "run p.json --out r", 2, {"p.json"}).File("p.json", "[1, 2]\n"),
      C("part_nan_literal", "part JSON", "run p.json --out r", 2, {"p.json"})
          .File("p.json", ReplaceOnce(LeanPart(), "0.010", "NaN")),
      C("part_missing_surface", "part JSON", "run p.json --out r", 2, {"p.json", "surface"})
          .File("p.json", PartWithout("surface")),
      C("part_tools_without_radius", "part JSON", "run p.json --out r", 2, {"p.json", "tools[0].radius_mm"})
          .File("p.json", PartWith("/tools", nlohmann::json::array({{{"number", 2}}}))),
      C("part_effects_unknown", "part JSON", "run p.json --out r", 2, {"p.json", "wobble_um"})
          .File("p.json", PartWith("/machine/effects/wobble_um", 3)),
      C("run_part_missing", "part JSON", "run nope.json --out r", 2, {"nope.json"}),
      C("run_folder_without_parts", "part JSON", "run empty --out r", 2, {"empty"}).Setup("mkdir empty"),
      C("run_machine_profile_missing", "machine profile", "run {F}/part.json --machine virtual:nope --out r", 2,
        {"nope"}),
      C("run_machine_profile_bad_json", "machine profile", "run {F}/part.json --machine virtual:./prof.json --out r", 2,
        {"prof.json"})
          .File("prof.json", "{\"format\": \"formloop-machine-profile\", \n"),
      C("run_machine_profile_unknown_effect", "machine profile",
        "run {F}/part.json --machine virtual:./prof.json --out r", 2, {"prof.json", "wobble"})
          .File("prof.json",
                R"({"format": "formloop-machine-profile", "version": 1, "name": "p", "description": "d",
                   "model": {"format": "formloop-model", "version": 1, "effects": [{"name": "wobble", "parameters": {}}]}})"),
      C("run_measured_and_machine", "options", "run {F}/part.json --machine virtual --measured {F}/log.csv --out r", 2,
        {"--machine"}),
      C("run_kb_missing", "case library", "run {F}/part.json --kb nokb.sqlite --out r", 2, {"nokb.sqlite"}),
      C("run_kb_not_sqlite", "case library", "run {F}/part.json --kb kb.sqlite --out r", 2, {"kb.sqlite"})
          .File("kb.sqlite", "this is not a database\n"),
      // A retrieval concept that is not in the taxonomies: refused before the run folder exists (it used to
      // fail after the surface fit, leaving r.failed).
      C("run_kb_shape_family_unknown", "part JSON", "run p.json --kb kb.sqlite --out r --no-retain", 2,
        {"p.json", "shape_family", "sadle"})
          .File("p.json", PartWith("/shape_family", "sadle"))
          .Copy("kb.sqlite"),
      // A part record the library holds but a pooled run cannot read (issue 20): refused naming the case and field.
      C("run_kb_part_record_damaged", "case library", "run b.json --kb kb.sqlite --out r --no-report", 2,
        {"kb.sqlite", "case lean-a", "d_radius", "--pool-cases 0"})
          .File("a.json", PartWith("/name", "lean-a"))
          .File("b.json", PartWith("/name", "lean-b"))
          .Copy("kb.sqlite")
          .Setup("'" FORMLOOP_BINARY "' -q run a.json --kb kb.sqlite --out ra --no-report && rm -rf ra && sqlite3 "
                 "kb.sqlite \"UPDATE case_part_records SET record_json = json_remove(record_json, '$.d_radius');\"")
          .FailedFolder("r.failed"),
      C("run_pool_cases_negative", "options", "run {F}/part.json --pool-cases -1 --out r", 2, {"--pool-cases"}),

      // ---- probe logs
      C("log_missing_ax", "probe log", kAnalyse + "l.csv", 2, {"l.csv:1", "ax"})
          .File("l.csv", "id,x,y,z,ay,az,t\n1,0,0,0,0,-1,0\n"),
      C("log_not_a_number", "probe log", kAnalyse + "l.csv", 2, {"l.csv:4", "field 'y'"})
          .File("l.csv", LineOf("log.csv", 3, "3,1.0,abc,2.0,0,0,-1,12")),
      C("log_duplicate_id", "probe log", kAnalyse + "l.csv", 2, {"l.csv", "id"})
          .File("l.csv", LineOf("log.csv", 3, "1,1.0,1.0,2.0,0,0,-1,12")),
      C("log_id_not_in_plan", "probe log", kAnalyse + "l.csv --plan {F}/plan.json", 2, {"999"})
          .File("l.csv", LineOf("log.csv", 3, "999,1.0,1.0,2.0,0,0,-1,12")),
      C("log_approach_not_unit", "probe log", kAnalyse + "l.csv", 2, {"l.csv:4"})
          .File("l.csv", LineOf("log.csv", 3, "3,1.0,1.0,2.0,0,0,-5,12")),
      C("log_empty", "probe log", kAnalyse + "l.csv", 2, {"l.csv"}).File("l.csv", ""),
      C("log_nan_time", "probe log", kAnalyse + "l.csv", 2, {"l.csv:4", "'t'"})
          .File("l.csv", LineOf("log.csv", 3, "3,1.0,1.0,2.0,0,0,-1,nan")),
      C("log_huge_coordinate", "probe log", kAnalyse + "l.csv", 2, {"l.csv:4", "field 'x'"})
          .File("l.csv", LineOf("log.csv", 3, "3,1e300,1.0,2.0,0,0,-1,12")),
      C("log_two_points", "probe log", kAnalyse + "l.csv", 2, {"l.csv"})
          .File("l.csv", "id,x,y,z,ax,ay,az,t\n1,0,0,2,0,0,-1,0\n2,1,0,2,0,0,-1,1\n"),
      C("log_all_far_from_surface_run", "probe log", "run {F}/part.json --measured l.csv --out r", 2,
        {"l.csv", "search distance"})
          .File("l.csv", LogShifted(10))
          .FailedFolder("r.failed"),
      C("log_all_far_from_surface_analyse", "probe log", kAnalyse + "l.csv", 2, {"l.csv", "search distance"})
          .File("l.csv", LogShifted(10)),
      C("run_measured_missing", "probe log", "run {F}/part.json --measured nolog.csv --out r", 2, {"nolog.csv"}),
      C("log_utf16", "probe log", kAnalyse + "l.csv", 2, {"l.csv", "UTF-16"})
          .File("l.csv", std::string("\xFF\xFEi\0d\0,\0x\0\n\0", 12)),
      C("calibrate_log_missing_columns", "probe log", "calibrate sphere l.csv --radius 12.5 --ball 1", 2, {"l.csv:1"})
          .File("l.csv", "id,x,y,z\n1,0,0,13.5\n"),
      C("calibrate_log_too_few_points", "probe log", "calibrate sphere l.csv --radius 12.5 --ball 1", 2, {"l.csv"})
          .File("l.csv", "id,x,y,z,ax,ay,az,t\n1,0,0,13.5,0,0,-1,0\n2,0,13.5,0,0,-1,0,1\n"),
      C("diagnose_measured_bad", "probe log", "diagnose --measured l.csv --run {F}/run --out d", 2, {"l.csv:2"})
          .File("l.csv", "id,x,y,z,ax,ay,az,t\n1,0,0,zz,0,0,-1,0\n"),

      // ---- probing plans
      C("plan_json_normal_not_unit", "probing plan", kAnalyse + "{F}/log.csv --plan p.json", 2, {"p.json", "normal"})
          .File("p.json", Changed("plan.json", "\"normal\": [\n        0.", "\"normal\": [\n        5.")),
      C("plan_json_duplicate_id", "probing plan", kAnalyse + "{F}/log.csv --plan p.json", 2, {"p.json", "id"})
          .File("p.json", Changed("plan.json", "\"id\": 2,", "\"id\": 1,")),
      C("plan_json_count_mismatch", "probing plan", kAnalyse + "{F}/log.csv --plan p.json", 2, {"p.json", "count"})
          .File("p.json", Changed("plan.json", "\"count\": 64", "\"count\": 65")),
      C("plan_json_no_points", "probing plan", kAnalyse + "{F}/log.csv --plan p.json", 2, {"p.json", "points"})
          .File("p.json", "{\"count\": 0, \"points\": []}\n"),
      C("plan_json_syntax", "probing plan", kAnalyse + "{F}/log.csv --plan p.json", 2, {"p.json"})
          .File("p.json", "{\"points\": [\n"),
      C("plan_csv_missing_u", "probing plan",
        "simulate --run {F}/run --model {F}/model.json --probe-plan p.csv --out o.csv", 2, {"p.csv"})
          .File("p.csv", "id,v,x,y,z,nx,ny,nz\n1,0,0,0,0,0,0,1\n"),
      C("plan_csv_approach_outward", "probing plan",
        "simulate --run {F}/run --model {F}/model.json --probe-plan p.csv --out o.csv", 2, {"p.csv:2", "ax,ay,az"})
          .File("p.csv", "id,u,v,x,y,z,nx,ny,nz,ax,ay,az\n1,0,0,0,0,0,0,0,1,0,0,1\n"),

      // ---- programs (G-code) and side files
      C("nc_check_nominal_garbage", "G-code", kCheck, 2, {"n.ngc"})
          .File("n.ngc", "this is not a program\nG1 X\n")
          .File("c.ngc", [](const Fixtures& f) { return f.Read("comp.ngc"); })
          .File("s.csv", [](const Fixtures& f) { return f.Read("side.bin"); }),
      C("nc_check_compensated_truncated", "G-code", kCheck, 2, {"c.ngc"})
          .File("n.ngc", [](const Fixtures& f) { return f.Read("prog.ngc"); })
          .File("c.ngc", Head("comp.ngc", 700))
          .File("s.csv", [](const Fixtures& f) { return f.Read("side.bin"); }),
      C("nc_check_side_bad_columns", "side file", kCheck, 2, {"s.csv"})
          .File("n.ngc", [](const Fixtures& f) { return f.Read("prog.ngc"); })
          .File("c.ngc", [](const Fixtures& f) { return f.Read("comp.ngc"); })
          .File("s.csv", "a,b,c\n1,2,3\n"),
      C("nc_check_side_bad_number", "side file", kCheck, 2, {"s.csv:4"})
          .File("n.ngc", [](const Fixtures& f) { return f.Read("prog.ngc"); })
          .File("c.ngc", [](const Fixtures& f) { return f.Read("comp.ngc"); })
          .File("s.csv",
                "# formloop compensation side file\n# source: x\ncl_index,pass,nominal_line,compensated_line,"
                "nominal_x,nominal_y,nominal_z,offset_x,offset_y,offset_z,ds_um,u,v,nx,ny,nz,kind\n"
                "0,0,12,12,x,y,z,0,0,0,0,0,0,0,0,1,lead-in\n"),
      C("nc_check_side_compact_cut_short", "side file", kCheck, 2, {"s.csv", "cut short"})
          .File("n.ngc", [](const Fixtures& f) { return f.Read("prog.ngc"); })
          .File("c.ngc", [](const Fixtures& f) { return f.Read("comp.ngc"); })
          .File("s.csv", Head("side.bin", 400)),
      C("nc_check_wrong_dialect", "G-code", kCheck + " --dialect heidenhain", 2, {"n.ngc"})
          .File("n.ngc", [](const Fixtures& f) { return f.Read("prog.ngc"); })
          .File("c.ngc", [](const Fixtures& f) { return f.Read("comp.ngc"); })
          .File("s.csv", [](const Fixtures& f) { return f.Read("side.bin"); }),
      C("nc_check_huge_coordinate", "G-code", kCheck, 2, {"c.ngc:"})
          .File("n.ngc", [](const Fixtures& f) { return f.Read("prog.ngc"); })
          .File("c.ngc",
                [](const Fixtures& f) {
                  std::string text = f.Read("comp.ngc");
                  const auto at = text.find("\nG1 X");
                  return at == std::string::npos ? text : text.replace(at + 5, 0, "1e300");
                })
          .File("s.csv", [](const Fixtures& f) { return f.Read("side.bin"); }),
      C("nc_compensate_nominal_garbage", "G-code", kCompensate + "--nominal n.ngc --out p.ngc --side s.csv", 2,
        {"n.ngc"})
          .Copy("tp.csv")
          .Copy("field.csv")
          .File("n.ngc", "G1 X1 Y\n"),

      // ---- tool-path files
      C("toolpath_without_options", "tool-path file", "nc post --toolpath t.csv --out p.ngc", 2, {"t.csv"})
          .File("t.csv", LineOf("tp.csv", 1, "# no options here")),
      C("toolpath_bad_number", "tool-path file", "nc post --toolpath t.csv --out p.ngc", 2, {"t.csv:5"})
          .File("t.csv", LineOf("tp.csv", 4, "0,lead-in,-35,-40,abc,-41,0.9,0,0,1,0")),
      C("toolpath_huge_coordinate", "tool-path file", "nc post --toolpath t.csv --out p.ngc", 2, {"t.csv:5"})
          .File("t.csv", LineOf("tp.csv", 4, "0,lead-in,-35,-40,1e300,-41,0.9,0,0,1,0")),
      C("toolpath_unknown_kind", "tool-path file", "nc post --toolpath t.csv --out p.ngc", 2, {"t.csv:5", "kind"})
          .File("t.csv", LineOf("tp.csv", 4, "0,wiggle,-35,-40,-36,-41,0.9,0,0,1,0")),
      C("toolpath_empty", "tool-path file", "nc post --toolpath t.csv --out p.ngc", 2, {"t.csv"}).File("t.csv", ""),
      C("toolpath_options_bad_json", "tool-path file", "nc post --toolpath t.csv --out p.ngc", 2, {"t.csv:2"})
          .File("t.csv", LineOf("tp.csv", 1, "# options: {\"scallop_um\": ")),
      C("toolpath_options_scallop_negative", "tool-path file", "nc post --toolpath t.csv --out p.ngc", 2,
        {"t.csv", "scallop_um"})
          .File("t.csv", Changed("tp.csv", "\"scallop_um\":20.0", "\"scallop_um\":-1")),

      // ---- systematic fields (u, v, ds_um)
      C("field_missing_ds", "field CSV", kCompensate + "--out p.ngc --side s.csv", 2, {"field.csv", "ds_um"})
          .Copy("tp.csv")
          .File("field.csv", "u,v,d\n0,0,1\n1,0,1\n0,1,1\n1,1,2\n"),
      C("field_two_points", "field CSV", kCompensate + "--out p.ngc --side s.csv", 2, {"field.csv"})
          .Copy("tp.csv")
          .File("field.csv", "u,v,ds_um\n0,0,1\n1,0,1\n"),
      C("field_nan", "field CSV", kCompensate + "--out p.ngc --side s.csv", 2, {"field.csv:3"})
          .Copy("tp.csv")
          .File("field.csv", "u,v,ds_um\n0,0,1\n1,0,nan\n0,1,1\n1,1,2\n"),
      C("field_duplicate_points", "field CSV", kCompensate + "--out p.ngc --side s.csv", 2, {"field.csv"})
          .Copy("tp.csv")
          .File("field.csv", "u,v,ds_um\n0,0,1\n0,0,2\n0,0,3\n0,0,4\n"),
      C("field_offset_beyond_limit", "field CSV", kCompensate + "--out p.ngc --side s.csv", 1, {"exceeds the limit"})
          .Copy("tp.csv")
          .File("field.csv", "u,v,ds_um\n-60,-60,500\n60,-60,500\n-60,60,500\n60,60,500\n0,0,500\n"),

      // ---- case libraries
      C("kb_add_material_with_space", "case JSON", "kb add kb.sqlite c.json", 2,
        {"example-blade-001", "material", "h13 "})
          .Copy("kb.sqlite")
          .File("c.json",
                [](const Fixtures& f) {
                  nlohmann::json c =
                      nlohmann::json::parse(ReadText(fs::path(FORMLOOP_SOURCE_DIR) / "data/kb/example_case.json"));
                  c["part"]["material"] = "h13 ";
                  c["concepts"]["material"] = "h13 ";
                  c["descriptor"] = std::vector<double>(24, 1.0);
                  return c.dump(2);
                }),
      C("kb_add_short_descriptor", "case JSON", "kb add kb.sqlite c.json", 2, {"example-blade-001", "descriptor"})
          .Copy("kb.sqlite")
          .File("c.json",
                [](const Fixtures& f) {
                  nlohmann::json c =
                      nlohmann::json::parse(ReadText(fs::path(FORMLOOP_SOURCE_DIR) / "data/kb/example_case.json"));
                  c["descriptor"] = std::vector<double>(10, 1.0);
                  return c.dump(2);
                }),
      C("kb_add_descriptor_with_string", "case JSON", "kb add kb.sqlite c.json", 2, {"example-blade-001", "descriptor"})
          .Copy("kb.sqlite")
          .File("c.json",
                [](const Fixtures& f) {
                  nlohmann::json c =
                      nlohmann::json::parse(ReadText(fs::path(FORMLOOP_SOURCE_DIR) / "data/kb/example_case.json"));
                  std::vector<nlohmann::json> d(24, 1.0);
                  d[5] = "x";
                  c["descriptor"] = d;
                  return c.dump(2);
                }),
      C("kb_add_unknown_shape", "case JSON", "kb add kb.sqlite c.json", 2, {"example-blade-001", "shape", "teapot"})
          .Copy("kb.sqlite")
          .File("c.json",
                [](const Fixtures& f) {
                  nlohmann::json c =
                      nlohmann::json::parse(ReadText(fs::path(FORMLOOP_SOURCE_DIR) / "data/kb/example_case.json"));
                  c["concepts"]["shape"] = "teapot";
                  c["descriptor"] = std::vector<double>(24, 1.0);
                  return c.dump(2);
                }),
      C("kb_add_not_json", "case JSON", "kb add kb.sqlite c.json", 2, {"c.json"})
          .Copy("kb.sqlite")
          .File("c.json", "{ uid: x }\n"),
      C("kb_add_missing_uid", "case JSON", "kb add kb.sqlite c.json", 2, {"c.json", "uid"})
          .Copy("kb.sqlite")
          .File("c.json",
                [](const Fixtures& f) {
                  nlohmann::json c =
                      nlohmann::json::parse(ReadText(fs::path(FORMLOOP_SOURCE_DIR) / "data/kb/example_case.json"));
                  c.erase("uid");
                  return c.dump(2);
                }),
      C("kb_import_bad_line", "case library export", "kb import kb.sqlite e.jsonl", 2, {"e.jsonl:2"})
          .Copy("kb.sqlite")
          .Setup("'" FORMLOOP_BINARY "' -q kb export kb.sqlite --out full.jsonl && head -1 full.jsonl > e.jsonl && "
                 "echo '{\"uid\": ' >> e.jsonl && rm full.jsonl"),
      C("kb_import_library_file", "case library export", "kb import kb.sqlite kb.sqlite", 2, {"kb.sqlite"})
          .Copy("kb.sqlite"),
      C("kb_open_text_file", "case library", "kb list notkb.sqlite", 2, {"notkb.sqlite"})
          .File("notkb.sqlite", "hello\n"),
      C("kb_show_unknown_uid", "case library", "kb show kb.sqlite nope", 2, {"nope"}).Copy("kb.sqlite"),
      C("kb_remove_unknown_uid", "case library", "kb remove kb.sqlite nope", 2, {"nope"}).Copy("kb.sqlite"),
      C("kb_export_missing_library", "case library", "kb export missing.sqlite --out e.jsonl", 2, {"missing.sqlite"}),
      C("retrieve_missing_library", "case library", "retrieve --library missing.sqlite --part {F}/part.json", 2,
        {"missing.sqlite"}),
      C("retrieve_part_without_surface", "part JSON", "retrieve --library {F}/kb.sqlite --part p.json", 2,
        {"p.json", "surface"})
          .File("p.json", PartWithout("surface")),
      C("kb_rules_bad_file", "rules JSON", "kb rules kb.sqlite --set r.json", 2, {"r.json"})
          .Copy("kb.sqlite")
          .File("r.json", "{\"rules\": [{\"name\": 3}]}\n"),
      C("kb_train_tau_negative", "options", "kb train kb.sqlite --tau1 -1", 2, {"--tau1"}).Copy("kb.sqlite"),
      C("kb_init_over_text_file", "case library", "kb init notkb.sqlite", 2, {"notkb.sqlite"})
          .File("notkb.sqlite", "my notes, not a database\n"),
      C("kb_calibrate_max_cases_negative", "options", "kb calibrate kb.sqlite --max-cases -1", 2, {"--max-cases"})
          .Copy("kb.sqlite"),

      // ---- models and profiles
      C("simulate_model_not_json", "model JSON", "simulate --run {F}/run --model m.json --out o.csv", 2, {"m.json"})
          .File("m.json", "{\"effects\": [\n"),
      C("simulate_model_unknown_effect", "model JSON", "simulate --run {F}/run --model m.json --out o.csv", 2,
        {"m.json", "wobble"})
          .File("m.json",
                R"({"format": "formloop-model", "version": 1, "effects": [{"name": "wobble", "parameters": {}}]})"),
      C("simulate_model_parameter_string", "model JSON", "simulate --run {F}/run --model m.json --out o.csv", 2,
        {"m.json", "delta_r_um"})
          .File("m.json", R"({"format": "formloop-model", "version": 1,
                              "effects": [{"name": "tool_radius", "parameters": {"delta_r_um": "five"}}]})"),
      C("simulate_model_parameter_huge", "model JSON", "simulate --run {F}/run --model m.json --out o.csv", 2,
        {"m.json", "delta_r_um"})
          .File("m.json", R"({"format": "formloop-model", "version": 1,
                              "effects": [{"name": "tool_radius", "parameters": {"delta_r_um": 1e300}}]})"),
      C("diagnose_baseline_unknown_effect", "model JSON",
        "diagnose --measured {F}/log.csv --run {F}/run --baseline b.json --out d", 2, {"b.json", "wobble"})
          .File("b.json",
                R"({"format": "formloop-model", "version": 1, "effects": [{"name": "wobble", "parameters": {}}]})"),
      C("analyse_profile_bad_json", "probe profile", kAnalyse + "{F}/log.csv --probe-profile pp.json", 2, {"pp.json"})
          .File("pp.json", "{\"ball_radius_mm\": \n"),
      C("analyse_profile_negative_radius", "probe profile", kAnalyse + "{F}/log.csv --probe-profile pp.json", 2,
        {"pp.json", "ball_radius"})
          .File("pp.json", Changed("profile.json", "\"ball_radius_mm\": ", "\"ball_radius_mm\": -")),
      C("diagnose_features_bad", "feature file", "diagnose --features f.csv --out d", 2, {"f.csv"})
          .File("f.csv", "id,x_nom\n1,2\n"),

      // ---- options of every command
      C("surfaces_sample_huge", "options", "surfaces sample saddle --nu 100000 --nv 100000 --out s.csv", 2, {"--nu"}),
      C("surfaces_sample_one_row", "options", "surfaces sample saddle --nu 1 --nv 10 --out s.csv", 2, {"--nu"}),
      C("surfaces_sample_unknown", "options", "surfaces sample nope --out s.csv", 2, {"nope"}),
      C("surfaces_sample_bad_extension", "options", "surfaces sample saddle --out s.txtx", 2, {"s.txtx"}),
      C("fit_samples_huge", "options", "fit analytic:saddle --method scattered --samples 2000000000 --out q.step", 2,
        {"--samples"}),
      C("fit_grid_zero", "options", "fit analytic:saddle --grid 0x0 --out q.step", 2, {"--grid"}),
      C("fit_poles_huge", "options", "fit {F}/scan.csv --poles 1000x1000 --out q.step", 2, {"--poles"}),
      C("fit_method_bogus", "options", "fit {F}/scan.csv --method bogus --out q.step", 2, {"--method"}),
      C("fit_check_negative", "options", "fit analytic:saddle --check -5 --out q.step", 2, {"--check"}),
      C("fit_out_not_step", "options", "fit analytic:saddle --out q.stl", 2, {"q.stl"}),
      C("nc_path_fanuc_five_decimals", "options",
        "nc path --surface {F}/Q.step --dialect fanuc --decimals 5 --out p.nc", 2, {"--decimals"}),
      C("nc_path_scallop_tiny", "options", "nc path --surface {F}/Q.step --scallop-um 0.000001 --out p.ngc", 2,
        {"--scallop-um"}),
      C("nc_path_chord_tiny", "options", "nc path --surface {F}/Q.step --chord-um 1e-9 --out p.ngc", 2, {"--chord-um"}),
      C("nc_path_tool_radius_negative", "options", "nc path --surface {F}/Q.step --tool-radius-mm -1 --out p.ngc", 2,
        {"radius"}),
      C("nc_path_dialect_unknown", "options", "nc path --surface {F}/Q.step --dialect haas --out p.ngc", 2,
        {"--dialect", "haas"}),
      C("nc_path_feed_above_machine", "options", "nc path --surface {F}/Q.step --feed 50000 --out p.ngc", 2,
        {"--feed"}),
      C("nc_path_spindle_above_machine", "options", "nc path --surface {F}/Q.step --spindle 90000 --out p.ngc", 2,
        {"--spindle"}),
      C("nc_path_travel_huge", "options", "nc path --surface {F}/Q.step --travel-mm 1e300 --out p.ngc", 2,
        {"--travel-mm"}),
      C("nc_path_line_length_negative", "options", "nc path --surface {F}/Q.step --max-line-length -3 --out p.ngc", 2,
        {"--max-line-length"}),
      C("nc_path_nothing_to_write", "options", "nc path --surface {F}/Q.step", 2, {"--out"}),
      C("nc_post_decimals_nine", "options", "nc post --toolpath {F}/tp.csv --decimals 9 --out p.ngc", 2,
        {"--decimals"}),
      C("nc_compensate_max_offset_huge", "options", kCompensate + "--max-offset-um 1e9 --out p.ngc --side s.csv", 2,
        {"--max-offset-um"})
          .Copy("tp.csv")
          .Copy("field.csv"),
      C("nc_probe_grid_one", "options", "nc probe --surface {F}/Q.step --grid 1x1 --out p.ngc", 2, {"--grid"}),
      C("nc_probe_count_huge", "options", "nc probe --surface {F}/Q.step --count 2000000000 --out p.ngc", 2,
        {"--count"}),
      C("nc_probe_search_zero", "options", "nc probe --surface {F}/Q.step --search-mm 0 --out p.ngc", 2, {"search"}),
      C("nc_probe_min_gap_zero", "options", "nc probe --surface {F}/Q.step --min-gap-mm 0 --out p.ngc", 2,
        {"--min-gap-mm"}),
      C("nc_probe_shank_negative", "options", "nc probe --surface {F}/Q.step --shank-radius-mm -1 --out p.ngc", 2,
        {"--shank-radius-mm"}),
      C("nc_probe_clearance_huge", "options", "nc probe --surface {F}/Q.step --clearance-mm 1e6 --out p.ngc", 2,
        {"clearance"}),
      C("moran_knn_zero", "options", "analyse moran --points t.csv --value v --knn 0 --style W", 2, {"--knn"})
          .File("t.csv", "x,y,v\n0,0,1\n1,0,2\n0,1,3\n1,1,5\n2,2,4\n"),
      C("moran_permutations_huge", "options",
        "analyse moran --points t.csv --value v --knn 1 --style W --permutations 2000000000", 2, {"--permutations"})
          .File("t.csv", "x,y,v\n0,0,1\n1,0,2\n0,1,3\n1,1,5\n2,2,4\n"),
      C("moran_style_bad", "options", "analyse moran --points t.csv --value v --knn 1 --style Q", 2, {"--style"})
          .File("t.csv", "x,y,v\n0,0,1\n1,0,2\n0,1,3\n1,1,5\n2,2,4\n"),
      C("moran_two_weights", "options", "analyse moran --points t.csv --value v --knn 1 --delaunay --style W", 2,
        {"--knn"})
          .File("t.csv", "x,y,v\n0,0,1\n1,0,2\n0,1,3\n1,1,5\n2,2,4\n"),
      C("analyse_max_distance_negative", "options", kAnalyse + "{F}/log.csv --max-distance-mm -1", 2,
        {"--max-distance-mm"}),
      C("analyse_register_bogus", "options", kAnalyse + "{F}/log.csv --register tq", 2, {"--register"}),
      C("analyse_knn_zero", "options", kAnalyse + "{F}/log.csv --knn 0", 2, {"--knn"}),
      C("analyse_no_out", "options", "analyse --surface {F}/Q.step --probe-log {F}/log.csv", 2, {"--out"}),
      C("calibrate_radius_negative", "options", "calibrate sphere {F}/sphere.csv --radius -1 --ball 1", 2, {"radius"}),
      C("calibrate_lobes_nine", "options", "calibrate sphere {F}/sphere.csv --radius 12.5 --ball 1 --lobes 9", 2,
        {"--lobes"}),
      C("synth_sphere_points_huge", "options", "calibrate synth-sphere --out s.csv --points 1000000000", 2,
        {"--points"}),
      C("regress_only_unknown", "options", "regress --parts {DATA}/regress/parts --only nope --out reg", 2, {"nope"}),
      C("report_not_a_run_folder", "options", "report rr", 2, {"rr"}).Setup("mkdir rr && echo keep > rr/keep.txt"),
      C("retrieve_top_zero", "options", "retrieve --library {F}/kb.sqlite --part {F}/part.json --top 0", 2, {"--top"}),
      C("log_level_bogus", "options", "--log-level loud surfaces list", 2, {"loud"}),
      C("diagnose_nothing_measured", "options", "diagnose --run {F}/run --out d", 2, {"--measured"}),
      C("simulate_run_missing", "options", "simulate --run norun --model {F}/model.json --out o.csv", 2, {"norun"}),
  };
  return cases;
}

}  // namespace formloop::bad_input
