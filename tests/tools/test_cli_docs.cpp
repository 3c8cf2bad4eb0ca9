// The commands the user's manual shows (README's tour, the command blocks of docs/) against the
// tool's own help: each names an existing command, only options that command has, and every
// option it requires. A renamed option or a forgotten --out then fails here, not in a
// newcomer's shell.
#include <gtest/gtest.h>

#include <fstream>
#include <regex>
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
    // The tool as $S or by name; one line may run several commands ("a && b").
    const std::regex tool(R"((?:^|[\s'])(?:\$S|stereoloc) )");
    for (std::sregex_iterator it(pending.begin(), pending.end(), tool), end; it != end; ++it) {
      const size_t start = static_cast<size_t>(it->position() + it->length());
      const size_t stop = pending.find("&&", start);
      std::string command = pending.substr(start, stop == std::string::npos ? std::string::npos : stop - start);
      command.erase(command.find_last_not_of(" '") + 1);
      out.push_back(command);
    }
    pending.clear();
  }
  return out;
}

struct CommandHelp {
  std::set<std::string> options, required;
};

// The options of `command` ("refine", "import mrclam") as its --help lists them.
CommandHelp helpOf(const std::string& command) {
  const test::CliRun r = test::runCli(command + " --help");
  EXPECT_EQ(r.exit_code, 0) << command << ": " << r.output;
  CommandHelp h;
  const std::regex option(R"(^\s+(?:-\w,)?(--[a-z0-9-]+)\b(.*)$)");
  std::istringstream in(r.output);
  for (std::string line; std::getline(in, line);) {
    std::smatch m;
    if (!std::regex_search(line, m, option)) continue;
    h.options.insert(m[1]);
    if (m[2].str().find("REQUIRED") != std::string::npos) h.required.insert(m[1]);
  }
  return h;
}

void checkCommands(const std::vector<std::string>& commands, const std::string& source) {
  ASSERT_FALSE(commands.empty()) << source;
  for (const std::string& line : commands) {
    std::istringstream words(line);
    std::vector<std::string> w;
    for (std::string x; words >> x;) w.push_back(x);
    ASSERT_FALSE(w.empty()) << source;
    std::string command = w[0];
    if (w.size() > 1 && ((command == "import" && w[1] == "mrclam") || (command == "study" && w[1] == "merge")))
      command += " " + w[1];
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
    const std::regex synopsis("`([^`]*)`");
    for (std::sregex_iterator it(cell.begin(), cell.end(), synopsis), end; it != end; ++it) {
      std::string text = (*it)[1];
      text = std::regex_replace(text, std::regex(R"([\[\]])"), " ");
      std::istringstream words(text);
      std::vector<std::string> w;
      for (std::string x; words >> x;) w.push_back(x);
      if (w.empty()) continue;
      std::string command = w[0];
      if (w.size() > 1 && ((command == "import" && w[1] == "mrclam") || (command == "study" && w[1] == "merge")))
        command += " " + w[1];
      const CommandHelp help = helpOf(command);
      for (const std::string& x : w) {
        if (x.rfind("--", 0) != 0) continue;
        EXPECT_TRUE(help.options.count(x)) << "docs/cli.md: `" << (*it)[1] << "`: " << command << " has no option " << x;
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
