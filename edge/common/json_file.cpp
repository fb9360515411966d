#include "common/json_file.h"

#include <fstream>
#include <sstream>

namespace alacs {

Result<cv::FileStorage> openJsonFile(const std::string& path, const std::string& what) {
  std::ifstream in(path);
  if (!in) return Status(Error::kNotFound, what + " '" + path + "' cannot be opened");
  std::stringstream text;
  text << in.rdbuf();
  cv::FileStorage fs;
  try {
    // In-memory parse: FileStorage guesses the format from a file name's extension.
    if (!fs.open(text.str(), cv::FileStorage::READ | cv::FileStorage::MEMORY | cv::FileStorage::FORMAT_JSON))
      return Status(Error::kBadInput, what + " '" + path + "' is not valid JSON");
  } catch (const cv::Exception& e) {
    return Status(Error::kBadInput, what + " '" + path + "' is not valid JSON: " + e.msg);
  }
  return fs;
}

}  // namespace alacs
