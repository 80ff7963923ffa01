// The BehaviorTree.CPP oracle: load a tree file of built-in nodes with BT.CPP's own
// factory, tick it N times, print what happened as JSON on stdout.
//
//   btcpp_oracle TREE.xml --ticks N [--exactly-once] [--source TEXT]
//
// The output has the shape of `canguard tree TREE.xml --tick N --json`
// ({"ticks": [...], "blackboard": {...}}), so the two compare key by key:
//   ticks       the root status after each tickOnce() (or tickExactlyOnce())
//   blackboard  the root blackboard's entries, each value as BT.CPP converts it to
//               a string (Any::cast<std::string>: numbers with std::to_string, so a
//               double prints "%f"); queues and vectors as "a;b;c"; null when the
//               entry exists but holds no value yet
//   types       each entry's type: the port type that created it, else the value's
//   error       null, or {"phase": "load"|"tick", "tick": k, "message": "..."}:
//               BT.CPP threw while loading the file or during tick k (1-based);
//               "ticks" then holds the ticks that returned before it
// Exit status 0 whenever the JSON was written (also for a recorded error).

#include <algorithm>
#include <cstdlib>
#include <deque>
#include <iostream>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <vector>

#include "behaviortree_cpp/bt_factory.h"
#include "behaviortree_cpp/contrib/json.hpp"

namespace
{
using Json = nlohmann::ordered_json;

struct Options
{
  std::string file;
  int ticks = 1;
  bool exactly_once = false;
  std::string source;
};

[[noreturn]] void usage(const std::string& why)
{
  std::cerr << "btcpp_oracle: " << why << "\n"
            << "usage: btcpp_oracle TREE.xml --ticks N [--exactly-once] [--source TEXT]\n";
  std::exit(2);
}

Options parseArgs(int argc, char** argv)
{
  Options opt;
  for(int i = 1; i < argc; i++)
  {
    const std::string arg = argv[i];
    if(arg == "--ticks" && i + 1 < argc)
    {
      opt.ticks = std::atoi(argv[++i]);
      if(opt.ticks < 1)
      {
        usage("--ticks: expected a number of ticks >= 1");
      }
    }
    else if(arg == "--exactly-once")
    {
      opt.exactly_once = true;
    }
    else if(arg == "--source" && i + 1 < argc)
    {
      opt.source = argv[++i];
    }
    else if(!arg.empty() && arg[0] != '-' && opt.file.empty())
    {
      opt.file = arg;
    }
    else
    {
      usage("unexpected argument '" + arg + "'");
    }
  }
  if(opt.file.empty())
  {
    usage("no tree file given");
  }
  return opt;
}

template <typename Seq>
std::string joinElements(const Seq& seq)
{
  std::string out;
  for(const auto& item : seq)
  {
    if(!out.empty())
    {
      out += ';';
    }
    out += BT::Any(item).cast<std::string>();
  }
  return out;
}

// The containers a tree of built-in nodes can put on the blackboard (the Loop
// nodes' queues), printed as the "a;b;c" text BT.CPP reads them from.
template <typename T>
std::optional<std::string> containerText(const BT::Any& value)
{
  if(value.isType<BT::SharedQueue<T>>())
  {
    const auto queue = value.cast<BT::SharedQueue<T>>();
    return queue ? joinElements(*queue) : std::string();
  }
  if(value.isType<std::vector<T>>())
  {
    return joinElements(value.cast<std::vector<T>>());
  }
  return std::nullopt;
}

Json valueText(const BT::Any& value)
{
  if(value.empty())
  {
    return nullptr;
  }
  if(value.isString() || value.isNumber())
  {
    return value.cast<std::string>();
  }
  for(const auto& text : { containerText<int>(value), containerText<double>(value),
                           containerText<std::string>(value) })
  {
    if(text)
    {
      return *text;
    }
  }
  if(auto text = containerText<bool>(value))
  {
    return *text;
  }
  return "<" + BT::demangle(value.type()) + ">";
}

Json rootBlackboard(BT::Tree& tree, Json& types)
{
  Json entries = Json::object();
  auto bb = tree.rootBlackboard();
  std::vector<std::string> keys;
  for(const auto& key : bb->getKeys())
  {
    keys.emplace_back(key);
  }
  std::sort(keys.begin(), keys.end());
  for(const auto& key : keys)
  {
    const auto entry = bb->getEntry(key);
    if(!entry)
    {
      continue;
    }
    const std::scoped_lock lock(entry->entry_mutex);
    auto type = entry->info.type();
    if(type == typeid(void) || type == typeid(BT::AnyTypeAllowed))
    {
      type = entry->value.type();
    }
    entries[key] = valueText(entry->value);
    types[key] = BT::demangle(type);
  }
  return entries;
}

Json errorJson(const std::string& phase, int tick, const std::string& message)
{
  Json err = Json::object();
  err["phase"] = phase;
  err["tick"] = tick;
  err["message"] = message;
  return err;
}

// BT.CPP prints diagnostics on std::cout (e.g. the blackboard's entries when a port's
// type clashes); while it runs they go to stderr, so stdout holds only the JSON.
class CoutToCerr
{
public:
  CoutToCerr() : saved_(std::cout.rdbuf(std::cerr.rdbuf()))
  {}
  ~CoutToCerr()
  {
    std::cout.rdbuf(saved_);
  }
  CoutToCerr(const CoutToCerr&) = delete;
  CoutToCerr& operator=(const CoutToCerr&) = delete;

private:
  std::streambuf* saved_;
};

Json run(const Options& opt)
{
  const CoutToCerr quiet;

  Json out = Json::object();
  out["btcpp"] = opt.source.empty() ? std::string(BT::LibraryVersionString()) : opt.source;
  out["mode"] = opt.exactly_once ? "tickExactlyOnce" : "tickOnce";
  out["ticks"] = Json::array();
  out["blackboard"] = Json::object();
  out["types"] = Json::object();
  out["error"] = nullptr;

  BT::BehaviorTreeFactory factory;
  std::unique_ptr<BT::Tree> tree;
  try
  {
    tree = std::make_unique<BT::Tree>(factory.createTreeFromFile(opt.file));
  }
  catch(const std::exception& exc)
  {
    out["error"] = errorJson("load", 0, exc.what());
    return out;
  }

  for(int i = 0; i < opt.ticks; i++)
  {
    try
    {
      const auto status = opt.exactly_once ? tree->tickExactlyOnce() : tree->tickOnce();
      out["ticks"].push_back(BT::toStr(status));
    }
    catch(const std::exception& exc)
    {
      out["error"] = errorJson("tick", i + 1, exc.what());
      break;
    }
  }
  Json types = Json::object();
  out["blackboard"] = rootBlackboard(*tree, types);
  out["types"] = types;
  return out;
}

}  // namespace

int main(int argc, char** argv)
{
  const Options opt = parseArgs(argc, argv);
  const Json out = run(opt);
  std::cout << out.dump(2) << std::endl;
  return 0;
}
