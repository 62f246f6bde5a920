
#ifndef PYTHONFMU_LOGGER_HPP
#define PYTHONFMU_LOGGER_HPP

#include "fmi2Functions.h"

#include <algorithm>
#include <string>
#include <vector>

namespace pythonfmu
{

class PyLogger
{

public:
    explicit PyLogger(std::string instanceName)
        : instanceName_(std::move(instanceName))
    { }

    void setDebugLogging(bool flag, const std::vector<std::string>& categories = {})
    {
        debugLogging_ = flag;
        categories_ = categories;
    }

    // Logs a message.
    void log(fmi2Status s, const std::string& message)
    {
        log(s, "", message);
    }

    void log(fmi2Status s, const std::string& category, const std::string& message)
    {
        // LMNCell: errors are always reported (the FMI 2.0 standard: with logging off the FMU
        // still calls the logger for errors); everything else only with logging on
        if (s == fmi2Error || s == fmi2Fatal) {
            debugLog(s, category, message);
        } else if (debugLogging_) {
            if (categories_.empty() || named(category) || named("logAll")) {   // LMNCell: logAll
                debugLog(s, category, message);
            }
        }
    }

    // LMNCell: a message that reaches the logger whether logging is on or not (a host's own
    // mistake in fmi2SetDebugLogging, reported with the status the call returns)
    void report(fmi2Status s, const std::string& message)
    {
        debugLog(s, "", message);
    }

    virtual ~PyLogger() = default;

private:
    bool debugLogging_{false};

    bool named(const std::string& category) const
    {
        return std::find(categories_.begin(), categories_.end(), category) != categories_.end();
    }

protected:
    std::string instanceName_;
    std::vector<std::string> categories_;

    virtual void debugLog(fmi2Status s, const std::string& category, const std::string& message) = 0;
};

} // namespace pythonfmu

#endif // PYTHONFMU_LOGGER_HPP
