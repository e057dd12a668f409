/*
 * The Heater tuning tab: the server's session state (GET /api/plugin/heater_twin), kept current by the
 * plugin's messages ({state}, {line}, {progress}, {message}); the buttons post start, paste and apply.
 */
$(function () {
    var PLUGIN = "heater_twin";
    var CONSOLE_LINES = 400; // as the server keeps (octoprint_heater_twin/session.py)
    var GAIN_DIGITS = 4; // significant digits, as twin-tune writes the gains in the commands it proposes

    function HeaterTwinViewModel(parameters) {
        var self = this;
        self.loginState = parameters[0];
        self.settings = parameters[1];
        self.access = parameters[2];

        self.heater = ko.observable("extruder");
        self.targetC = ko.observable(210);
        self.cycles = ko.observable(8);
        self.pasted = ko.observable("");

        self.phase = ko.observable("idle");
        self.busy = ko.observable(false);
        self.doing = ko.observable("");
        self.error = ko.observable(null);
        self.run = ko.observable(null);
        self.console = ko.observableArray([]);
        self.progress = ko.observable(null);
        self.messages = ko.observableArray([]);
        self.answer = ko.observable(null);
        self.applied = ko.observable(null);
        self.noPlot = ko.observable(null);
        self.hasPlot = ko.observable(false);
        self.currentFrom = ko.observable(null);

        self.mayControl = ko.pureComputed(function () {
            return self.loginState.hasPermission(self.access.permissions.CONTROL);
        });
        self.canStart = ko.pureComputed(function () {
            return self.mayControl() && !self.busy();
        });
        self.canPaste = ko.pureComputed(function () {
            return self.canStart() && self.pasted().trim().length > 0;
        });
        self.canApply = ko.pureComputed(function () {
            return self.mayControl() && (self.phase() === "answer" || self.phase() === "applied");
        });
        self.m303 = ko.pureComputed(function () {
            var e = self.heater() === "heater_bed" ? "E-1" : "E0";
            return "M303 " + e + " S" + self.targetC() + " C" + self.cycles();
        });
        self.consoleText = ko.pureComputed(function () {
            return self.console().join("\n");
        });
        self.progressText = ko.pureComputed(function () {
            var p = self.progress();
            return p ? ": " + p.step + " " + p.done + "/" + p.total : "";
        });
        self.progressPercent = ko.pureComputed(function () {
            var p = self.progress();
            return p && p.total ? Math.round((100 * p.done) / p.total) : 0;
        });
        self.plotUrl = ko.pureComputed(function () {
            if (!self.hasPlot() || !self.run()) return null;
            return BASEURL + "api/plugin/" + PLUGIN + "?plot=" + self.run();
        });

        // per plant, the answer's row (else the best other candidate's: what did not beat yours) and yours
        self.proofRows = ko.pureComputed(function () {
            var a = self.answer();
            if (!a) return [];
            var shown = {};
            return _.filter(a.proof, function (row) {
                var key = row.member + (row.candidate === "yours" ? "/yours" : "/other");
                var pick = row.candidate === "yours" || row.candidate === "answer" || !a.answer;
                if (!pick || shown[key]) return false;
                shown[key] = true;
                return true;
            });
        });

        self.verdictText = function () {
            var a = self.answer();
            if (!a) return "";
            return a.verdict === "new gains" ? "New gains" : "Keep your gains";
        };
        self.gain = function (value) {
            return String(parseFloat(Number(value).toPrecision(GAIN_DIGITS)));
        };
        // a proof row's [mean, worst] to ``decimals`` (as twin-tune's own table: 2 for C, 3 for chatter)
        self.meanWorst = function (pair, decimals) {
            return pair ? pair[0].toFixed(decimals) + " / " + pair[1].toFixed(decimals) : "-";
        };
        self.memberText = function (member) {
            // delta: Akaike units behind the best fit (twin-tune's plants the log allows)
            var delta = member.delta === null || member.delta === undefined ? "" : "(delta " + member.delta.toFixed(1) + ") ";
            return delta + member.replay;
        };

        // a heater's target is the settings' when the heater is chosen
        self.settingsTarget = function (heater) {
            var s = self.settings.settings.plugins.heater_twin;
            return heater === "heater_bed" ? s.bed_target_c() : s.extruder_target_c();
        };
        self.heater.subscribe(function (heater) {
            self.targetC(self.settingsTarget(heater));
        });

        self.fromState = function (state) {
            self.phase(state.phase);
            self.busy(state.busy);
            self.doing(state.doing || "");
            self.error(state.error);
            self.run(state.run);
            self.console(state.console);
            self.progress(state.progress);
            self.messages(state.messages);
            self.answer(state.answer);
            self.applied(state.applied);
            self.hasPlot(state.plot);
            self.noPlot(state.no_plot);
            self.currentFrom(state.current_from);
        };

        self.request = function (command, data) {
            self.error(null);
            OctoPrint.simpleApiCommand(PLUGIN, command, data || {})
                .done(self.fromState)
                .fail(function (xhr) {
                    var reply = xhr.responseJSON || {};
                    self.error(reply.error || xhr.statusText || "The request failed");
                });
        };
        self.start = function () {
            self.request("start", {heater: self.heater(), target_c: self.targetC(), cycles: self.cycles()});
        };
        self.paste = function () {
            self.request("paste", {heater: self.heater(), text: self.pasted()});
        };
        self.apply = function () {
            self.request("apply");
        };

        self.refresh = function () {
            if (!self.loginState.hasPermission(self.access.permissions.STATUS)) return;
            OctoPrint.simpleApiGet(PLUGIN).done(self.fromState);
        };

        // the tab starts from the settings, and follows them when the settings dialog closes (not during a run)
        self.fromSettings = function () {
            if (self.busy()) return;
            var s = self.settings.settings.plugins.heater_twin;
            self.heater(s.heater());
            self.targetC(self.settingsTarget(self.heater()));
            self.cycles(s.cycles());
        };
        self.onBeforeBinding = self.onSettingsHidden = self.fromSettings;
        self.onStartupComplete = self.onUserLoggedIn = self.refresh;

        self.onDataUpdaterPluginMessage = function (plugin, message) {
            if (plugin !== PLUGIN) return;
            if (message.state) {
                self.fromState(message.state);
            } else if (message.line !== undefined) {
                self.console.push(message.line);
                if (self.console().length > CONSOLE_LINES) self.console.shift();
                var pre = document.getElementById("heater_twin_console");
                if (pre) pre.scrollTop = pre.scrollHeight;
            } else if (message.progress) {
                self.progress(message.progress);
            } else if (message.message !== undefined) {
                self.messages.push(message.message);
            }
        };
    }

    OCTOPRINT_VIEWMODELS.push({
        construct: HeaterTwinViewModel,
        dependencies: ["loginStateViewModel", "settingsViewModel", "accessViewModel"],
        elements: ["#tab_plugin_heater_twin"]
    });
});
