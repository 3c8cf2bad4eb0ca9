// The commands the user's manual shows (README's tour, the command blocks of docs/) against the
// tool's own help: each names an existing command, only options that command has, and every
// option it requires. A renamed option or a forgotten --out then fails here, not in a
// newcomer's shell.
#include <gtest/gtest.h>

#include <cctype>
#include <fstream>
#include <set>
#include <sstream>
#include <string>
#include <vector>

#include "cli_util.h"
#include "test_util.h"

namespace stereoloc {
namespace {

// The shell commands of the ```sh blocks of `markdown` (after `after`, when given) that run the
// tool ($S ...), continuation lines joined and comments dropped.
std::vector<std::string> toolCommands(const std::string& markdown, const std::string& after = "") {
  std::vector<std::string> out;
  std::istringstream in(markdown.substr(after.empty() ? 0 : markdown.find(after)));
  bool in_block = false;
  std::string pending;
  for (std::string line; std::getline(in, line);) {
    if (line.rfind("```", 0) == 0) {
      in_block = !in_block && line == "```sh";
      continue;
    }
    if (!in_block) continue;
    const size_t hash = line.find(" #");
    if (hash != std::string::npos) line = line.substr(0, hash);
    const bool continued = !line.empty() && line.back() == '\\';
    pending += continued ? line.substr(0, line.size() - 1) : line;
    if (continued) continue;
    // The tool as $S or by name, at the start or after a space or quote; one line may run
    // several commands ("a && b").
    for (const std::string& name : {std::string("$S "), std::string("stereoloc ")}) {
      for (size_t at = pending.find(name); at != std::string::npos; at = pending.find(name, at + 1)) {
        if (at > 0 && pending[at - 1] != ' ' && pending[at - 1] != '\'') continue;
        const size_t start = at + name.size(), stop = pending.find("&&", start);
        std::string command = pending.substr(start, stop == std::string::npos ? std::string::npos : stop - start);
        command.erase(command.find_last_not_of(" '") + 1);
        out.push_back(command);
      }
    }
    pending.clear();
  }
  return out;
}

std::vector<std::string> wordsOf(const std::string& text) {
  std::istringstream in(text);
  std::vector<std::string> w;
  for (std::string x; in >> x;) w.push_back(x);
  return w;
}

// The (sub)command a command line's words start with: "refine", or "import mrclam", "study merge".
std::string commandOf(const std::vector<std::string>& w) {
  if (w.size() > 1 && ((w[0] == "import" && w[1] == "mrclam") || (w[0] == "study" && w[1] == "merge")))
    return w[0] + " " + w[1];
  return w[0];
}

struct CommandHelp {
  std::set<std::string> options, required;
};

// The options of `command` ("refine", "import mrclam") as its --help lists them.
CommandHelp helpOf(const std::string& command) {
  const test::CliRun r = test::runCli(command + " --help");
  EXPECT_EQ(r.exit_code, 0) << command << ": " << r.output;
  CommandHelp h;
  std::istringstream in(r.output);
  for (std::string line; std::getline(in, line);) {
    // An option line: indented, an optional short form ("-h,"), then --name.
    size_t k = line.find_first_not_of(' ');
    if (k == 0 || k == std::string::npos) continue;
    if (line.compare(k, 1, "-") == 0 && line.compare(k, 2, "--") != 0 && line.size() > k + 3 && line[k + 2] == ',')
      k += 3;
    if (line.compare(k, 2, "--") != 0) continue;
    size_t end = k + 2;
    while (end < line.size() && (std::islower(static_cast<unsigned char>(line[end])) ||
                                 std::isdigit(static_cast<unsigned char>(line[end])) || line[end] == '-'))
      ++end;
    const std::string name = line.substr(k, end - k);
    h.options.insert(name);
    if (line.find("REQUIRED", end) != std::string::npos) h.required.insert(name);
  }
  return h;
}

void checkCommands(const std::vector<std::string>& commands, const std::string& source) {
  ASSERT_FALSE(commands.empty()) << source;
  for (const std::string& line : commands) {
    const std::vector<std::string> w = wordsOf(line);
    ASSERT_FALSE(w.empty()) << source;
    const std::string command = commandOf(w);
    const CommandHelp help = helpOf(command);
    std::set<std::string> used;
    for (const std::string& x : w)
      if (x.rfind("--", 0) == 0) used.insert(x.substr(0, x.find('=')));
    for (const std::string& o : used)
      EXPECT_TRUE(help.options.count(o)) << source << ": `" << line << "`: " << command << " has no option " << o;
    for (const std::string& o : help.required)
      EXPECT_TRUE(used.count(o)) << source << ": `" << line << "`: " << command << " requires " << o;
  }
}

TEST(CliDocs, TheReadmeTourRunsCommandsAsTheyAre) {
  const std::string readme = test::readFile(std::string(STEREOLOC_SOURCE_DIR) + "/README.md");
  const std::vector<std::string> tour = toolCommands(readme, "## A five-minute tour");
  EXPECT_GE(tour.size(), 20u);
  checkCommands(tour, "README.md");
}

TEST(CliDocs, TheDocsRunCommandsAsTheyAre) {
  size_t n = 0;
  for (const char* page : {"on_a_robot.md", "realistic_world.md", "realtime.md", "cli.md"}) {
    const std::string path = std::string(STEREOLOC_SOURCE_DIR) + "/docs/" + page;
    const std::vector<std::string> commands = toolCommands(test::readFile(path));
    n += commands.size();
    checkCommands(commands, path);
  }
  EXPECT_GE(n, 20u);
}

// docs/cli.md's table of commands: every option a synopsis names (`refine DIR [--out F]`,
// several synopses per row possible) is one its command has.
TEST(CliDocs, TheCommandTableNamesOptionsTheCommandsHave) {
  std::istringstream in(test::readFile(std::string(STEREOLOC_SOURCE_DIR) + "/docs/cli.md"));
  size_t rows = 0;
  for (std::string line; std::getline(in, line);) {
    if (line.rfind("| `", 0) != 0) continue;
    const std::string cell = line.substr(2, line.find(" | ", 2) - 2);
    for (size_t open = cell.find('`'); open != std::string::npos; open = cell.find('`', open + 1)) {
      const size_t close = cell.find('`', open + 1);
      if (close == std::string::npos) break;
      const std::string synopsis = cell.substr(open + 1, close - open - 1);
      open = close;
      std::string text = synopsis;
      for (char& c : text)
        if (c == '[' || c == ']') c = ' ';
      const std::vector<std::string> w = wordsOf(text);
      if (w.empty()) continue;
      const std::string command = commandOf(w);
      const CommandHelp help = helpOf(command);
      for (const std::string& x : w) {
        if (x.rfind("--", 0) != 0) continue;
        EXPECT_TRUE(help.options.count(x)) << "docs/cli.md: `" << synopsis << "`: " << command << " has no option " << x;
      }
      ++rows;
    }
  }
  EXPECT_GE(rows, 15u);
}

// The check itself: a command without a required option, or with an option its command does
// not have, is caught.
TEST(CliDocs, TheCheckFindsAMissingRequiredOptionAndAnUnknownOne) {
  const std::string doc = "```sh\n$S refine d1 --calibrate odometry \\\n    --calibration-out c.yaml  # note\n```\n";
  const std::vector<std::string> commands = toolCommands(doc);
  ASSERT_EQ(commands.size(), 1u);
  EXPECT_EQ(commands[0], "refine d1 --calibrate odometry     --calibration-out c.yaml");
  const CommandHelp help = helpOf("refine");
  EXPECT_TRUE(help.required.count("--out"));
  EXPECT_TRUE(help.options.count("--calibration-out"));
  EXPECT_FALSE(help.options.count("--calibration-output"));
  EXPECT_TRUE(helpOf("import mrclam").options.count("--range-correction"));
}

}  // namespace
}  // namespace stereoloc
